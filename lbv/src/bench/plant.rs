//! The physical plant behind one thruster controller: a hall-sensored BLDC motor (or a brushed DC motor) turning a
//! propeller in water, its winding temperature and its water-sensor electrodes.
//!
//! # Model
//!
//! Everything is f64 and advanced by [`Plant::step`] with the time step the caller chooses (the bench uses 50 us).
//!
//! **Motor.** Star-connected, `pole_pairs` pole pairs, trapezoidal back-EMF: phase x carries
//! `e_x = ke * omega * f_x(theta_e)`, omega the mechanical speed (rad/s), theta_e = pole_pairs x mechanical angle and
//! f_A the shape of the firmware's commutation tests (+1 on [30, 150) degrees, -1 on [210, 330), linear between,
//! zero crossings at 0 and 180); B lags A by 120 degrees, C by 240. The halls are
//! [`hall_state_at`](thruster_fw::hall::hall_state_at) of theta_e, so every hall edge falls on a commutation point.
//!
//! **Brushed.** With [`MotorParams::brushed`] the motor is a DC motor between phases A and B (the controller's
//! H-bridge; C is not connected): its commutator keeps the back-EMF on the plateaus whatever the angle, A at +1 and
//! B at -1, so the pair's equations below hold at every angle: `i = (V - 2 ke omega) / 2R`, `T = 2 ke i`, with
//! `2R` the resistance between its terminals and `2 ke` its torque constant. It has no halls: the lines read 111
//! (the inputs' pull-ups), and the brush drop, armature reaction and commutation ripple are not modelled.
//!
//! **Bridge.** Complementary PWM averaged over the PWM period (the PWM frequency is far above every time constant
//! here): a [`PhaseDrive::Pwm`] phase sits at |duty| x V_supply on average, a [`PhaseDrive::Low`] phase at 0 V, a
//! [`PhaseDrive::Float`] phase carries no current (freewheeling through the body diodes after a commutation is not
//! modelled). The sign of the duty only selects the firmware's table: the bridge sees its magnitude. With the
//! connected phases S (at least two, else nothing flows) the star point settles where their currents sum to zero:
//! `v_n = mean_S(v_x - e_x)`, `i_x = (v_x - e_x - v_n) / R`. For the usual pair (Pwm phase p, Low phase l) this is
//! `i = (|duty| V - (e_p - e_l)) / 2R` from p to l. The current may go negative (synchronous rectification lets
//! it): a motor turning faster than the applied voltage brakes regeneratively and feeds the supply.
//! Torque is the electrical power over the speed, `T = ke * sum(f_x * i_x)`, i.e. `ke * i * (f_p - f_l)` for a
//! pair: correct forward commutation puts the Pwm phase on its +1 plateau and the Low phase on its -1 plateau, so
//! `T = 2 ke i > 0`; a wrong table meets a smaller or reversed back-EMF difference and gives less or negative
//! torque.
//!
//! **No winding inductance.** The electrical time constant of such a motor (L/R ~ 0.1-0.3 ms) is a few steps of
//! 50 us; leaving it out makes the current an algebraic function of drive, angle and speed, which is stable for any
//! step. The consequences: current steps instantly at each commutation (no ripple, no commutation dip), and the
//! current-sense reading follows the drive without lag. The average operating points are unaffected.
//!
//! **Load.** Propeller `prop_k * omega * |omega|` (both directions), viscous friction `friction * omega`, inertia
//! `inertia` (rotor, propeller and entrained water). The speed is integrated with a linearised implicit Euler step
//! (stable for any step), the angle with the trapezoidal rule. A step longer than [`MAX_SUBSTEP_S`] is cut into equal
//! sub-steps with the drive held.
//!
//! **Winding temperature.** One node: `C_th dT/dt = R * sum(i_x^2) - (T - T_water) / R_th`, solved exactly over each
//! sub-step (stable for any step). Copper resistance does not change with temperature.
//!
//! # Parameters ([`MotorParams::THRUSTER`]) and what they give
//!
//! A small ROV thruster in the SeaBotix BTD150 class on 24 V, with ideal commutation from its own halls (the
//! figures come from this module's tests, 50 us steps):
//!
//! | duty | speed | phase current | supply current |
//! |---|---|---|---|
//! | 25 % | ~1 440 rpm | ~0.4 A | ~0.1 A |
//! | 50 % | ~2 730 rpm | ~1.3 A | ~0.6 A |
//! | 100 % | ~5 000 rpm | ~4.0 A | ~4.0 A |
//!
//! The propeller load is quadratic, so with a stiff motor the speed is nearly proportional to the duty: the
//! firmware's speed loop needs about 88 % duty for its 4500 rpm full scale. A softer motor (more resistance) would
//! turn faster at half duty, but would then heat less at stall than at full speed, contrary to what the overtemp
//! fault is for. Stalled, the current is `|duty| x 24 V / 1.2 ohm`: 6 A at 30 % duty, 20 A at 100 %. Spin-up from
//! rest to 95 % of full speed takes about 0.1 s; coasting from full speed, the propeller brakes the rotor to
//! ~150 rpm in 3 s and ~7 rpm in 10 s (there is no static friction: it never quite stops).
//!
//! Thermal (15 C water, time constant R_th x C_th = 30 s): running at full speed dissipates ~19 W in the copper and
//! settles near 73 C; stalled at 30 % duty 43 W would settle near 145 C and the winding passes 110 C after ~40 s
//! (at 100 % duty stalled: ~2 s). After stopping it cools with the same 30 s time constant (from 73 C to below 25 C
//! in about a minute).
//!
//! # Robustness
//!
//! No input makes [`Plant::step`] panic or produce NaN: a non-finite or non-positive step advances nothing, a step
//! is taken at most [`MAX_STEP_S`], the supply is clamped to 0..=[`MAX_SUPPLY_V`] (NaN reads 0 V), and out-of-range
//! or non-finite parameters and ambient temperatures are clamped to sane values when used.

use core::f64::consts::{PI, TAU};

use thruster_fw::commutation::{BridgeDrive, PhaseDrive};
use thruster_fw::drive::Duty;
use thruster_fw::hall::{HallState, hall_state_at};

/// Longest sub-step of the integration; longer steps are cut into equal sub-steps of at most this.
pub const MAX_SUBSTEP_S: f64 = 50e-6;
/// Longest step one call advances; a longer one is cut to this.
pub const MAX_STEP_S: f64 = 1.0;
/// Highest supply voltage the bridge is taken to see; above it (or at +infinity) it reads this.
pub const MAX_SUPPLY_V: f64 = 1000.0;
/// Water temperature at power-up, and where a non-finite `ambient_c` is read.
pub const DEFAULT_AMBIENT_C: f64 = 15.0;
/// Water-sensor resistance of a dry housing: far above the 1 Mohm water threshold.
pub const DRY_WATER_OHMS: u32 = 20_000_000;

/// Backstop on the mechanical speed, rad/s (~9.5 million rpm): only absurd parameters come near it.
const MAX_OMEGA: f64 = 1.0e6;
/// Backstop on the winding temperature, deg C.
const MAX_WINDING_C: f64 = 1.0e6;
/// Absolute zero, deg C.
const ABSOLUTE_ZERO_C: f64 = -273.15;

/// The motor, propeller and thermal constants.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotorParams {
    /// Rotor pole pairs (0 is taken as 1).
    pub pole_pairs: u8,
    /// Winding resistance per phase (star), ohms; line to line is twice this.
    pub resistance_ohm: f64,
    /// Peak (plateau) phase back-EMF per mechanical rad/s, V s/rad. The torque constant of a driven pair on its
    /// plateaus is twice this, in N m/A.
    pub ke_v_s_per_rad: f64,
    /// Rotor, propeller and entrained water, kg m^2.
    pub inertia_kg_m2: f64,
    /// Propeller torque per (rad/s)^2, N m s^2.
    pub prop_k: f64,
    /// Viscous friction (bearings, seals), N m per rad/s.
    pub friction: f64,
    /// Winding to water, K/W.
    pub thermal_resistance_k_per_w: f64,
    /// Winding heat capacity, J/K.
    pub thermal_capacity_j_per_k: f64,
    /// A brushed DC motor between phases A and B instead of a BLDC motor (see the module documentation).
    pub brushed: bool,
}

impl MotorParams {
    /// A BTD150-class thruster: see the module documentation for what these give.
    ///
    /// 0.6 ohm per phase and ke 0.0183 V s/rad (a pair's torque constant 0.0366 N m/A): at 5000 rpm the plateau
    /// line-to-line back-EMF is 19.2 V, leaving 4.8 V across 1.2 ohm for 4 A. The propeller takes 0.137 N m at
    /// 5000 rpm (~72 W), the seals 0.010 N m. 5e-5 kg m^2 gives a ~30 ms mechanical time constant at full speed.
    /// 3 K/W and 10 J/K to the water: a 30 s thermal time constant.
    pub const THRUSTER: MotorParams = MotorParams {
        pole_pairs: 4,
        resistance_ohm: 0.6,
        ke_v_s_per_rad: 0.0183,
        inertia_kg_m2: 5.0e-5,
        prop_k: 5.0e-7,
        friction: 2.0e-5,
        thermal_resistance_k_per_w: 3.0,
        thermal_capacity_j_per_k: 10.0,
        brushed: false,
    };

    /// A brushed thruster of the same class: the same 1.2 ohm between its terminals and the same torque constant
    /// (thruster-fw's `Thresholds::armature_milliohms`), so the same speeds and currents as the BLDC motor on its
    /// plateaus, and a 20 A locked-rotor current at 24 V.
    pub const BRUSHED_THRUSTER: MotorParams = MotorParams {
        brushed: true,
        ..MotorParams::THRUSTER
    };

    /// The parameters as used: every value finite and within a range where the integration stays finite.
    fn checked(&self) -> CheckedParams {
        CheckedParams {
            resistance: finite_clamp(self.resistance_ohm, 1e-3, 1e6, Self::THRUSTER.resistance_ohm),
            ke: finite_clamp(self.ke_v_s_per_rad, 0.0, 10.0, Self::THRUSTER.ke_v_s_per_rad),
            inertia: finite_clamp(self.inertia_kg_m2, 1e-9, 1e3, Self::THRUSTER.inertia_kg_m2),
            prop_k: finite_clamp(self.prop_k, 0.0, 1.0, Self::THRUSTER.prop_k),
            friction: finite_clamp(self.friction, 0.0, 10.0, Self::THRUSTER.friction),
            r_th: finite_clamp(
                self.thermal_resistance_k_per_w,
                1e-6,
                1e6,
                Self::THRUSTER.thermal_resistance_k_per_w,
            ),
            c_th: finite_clamp(
                self.thermal_capacity_j_per_k,
                1e-6,
                1e9,
                Self::THRUSTER.thermal_capacity_j_per_k,
            ),
        }
    }
}

/// [`MotorParams`] checked for use.
#[derive(Debug, Clone, Copy, PartialEq)]
struct CheckedParams {
    resistance: f64,
    ke: f64,
    inertia: f64,
    prop_k: f64,
    friction: f64,
    r_th: f64,
    c_th: f64,
}

/// `x` clamped to `min..=max`, or `fallback` when it is not finite.
fn finite_clamp(x: f64, min: f64, max: f64, fallback: f64) -> f64 {
    if x.is_finite() { x.clamp(min, max) } else { fallback }
}

/// The motor, propeller, winding temperature and water sensor of one thruster, with fault injection.
#[derive(Debug, Clone, PartialEq)]
pub struct Plant {
    /// Motor constants.
    params: MotorParams,
    /// `params` clamped to what the model can integrate, as it uses them.
    checked: CheckedParams,
    /// Resistance between the water-sensor electrodes, ohms ([`DRY_WATER_OHMS`] at first). No dynamics.
    pub water_ohms: u32,
    /// Water (ambient) temperature, deg C ([`DEFAULT_AMBIENT_C`] at first).
    pub ambient_c: f64,
    /// The rotor is held (a rope in the propeller): the speed stays 0 whatever the torque.
    pub blocked: bool,
    /// The hall lines read this fixed state instead of the rotor's (e.g. 0b000: sensor unplugged).
    pub hall_fault: Option<HallState>,
    /// Mechanical angle, rad, in [0, 2 pi).
    angle_rad: f64,
    /// The electrical angle of `angle_rad`, degrees, in [0, 360) (kept with it: every look at the halls or the
    /// back-EMF needs it).
    electrical_deg: f64,
    /// Mechanical speed, rad/s, positive forward.
    omega: f64,
    /// Winding temperature, deg C.
    winding_c: f64,
    /// Current into phases A, B, C during the last sub-step, A (sums to zero).
    currents: [f64; 3],
    /// Current drawn from the supply during the last sub-step, A (negative while regenerating).
    supply_a: f64,
    /// Electromagnetic torque during the last sub-step, N m.
    torque: f64,
    /// The hall state at the end of the last step (what the controller last saw), for edge reporting.
    last_hall: HallState,
    /// The last thermal decay: its exponent `-h / tau` and `exp` of it.
    decay: Cached<(f64, f64)>,
    /// The electrical solution at the present state for this drive and duty, while nothing has moved since
    /// [`Plant::evaluate`] found it: the next [`Plant::advance`] starts from it.
    evaluated: Cached<Option<(BridgeDrive, Duty, Electrical)>>,
}

/// The electrical solution at one instant.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Electrical {
    currents: [f64; 3],
    supply_a: f64,
    torque: f64,
    /// d(torque)/d(omega) of the electrical torque, <= 0: the back-EMF damping, for the implicit speed step.
    damping: f64,
    /// Copper loss, W.
    copper_w: f64,
}

impl Plant {
    /// A plant at rest, at angle 0, winding and water at 15 C, dry, no fault.
    pub fn new(params: MotorParams) -> Self {
        let mut plant = Plant {
            checked: params.checked(),
            params,
            water_ohms: DRY_WATER_OHMS,
            ambient_c: DEFAULT_AMBIENT_C,
            blocked: false,
            hall_fault: None,
            angle_rad: 0.0,
            electrical_deg: 0.0,
            omega: 0.0,
            winding_c: DEFAULT_AMBIENT_C,
            currents: [0.0; 3],
            supply_a: 0.0,
            torque: 0.0,
            last_hall: HallState::from_bits(0),
            decay: Cached((0.0, 1.0)),
            evaluated: Cached(None),
        };
        plant.last_hall = plant.hall_state();
        plant
    }

    /// The same plant with the rotor at `mechanical_rad` (any finite value; non-finite reads 0).
    pub fn with_angle(mut self, mechanical_rad: f64) -> Self {
        self.set_angle(wrap_angle(mechanical_rad));
        self.last_hall = self.hall_state();
        self
    }

    /// Advance by `dt_s` seconds with `drive` applied at `duty` on `supply_v`. Returns true when the hall state
    /// read by [`Plant::hall_state`] differs from the one at the end of the previous step (a rotor edge, or a
    /// `hall_fault` set or cleared in between).
    ///
    /// A non-finite or non-positive `dt_s` advances nothing but still re-evaluates the currents and torque for this
    /// drive; a `dt_s` above [`MAX_STEP_S`] advances [`MAX_STEP_S`]. Steps above [`MAX_SUBSTEP_S`] are integrated
    /// in equal sub-steps with the drive held (so a long step may run past commutation points, as a real motor
    /// would under a frozen drive).
    pub fn step(&mut self, dt_s: f64, drive: BridgeDrive, duty: Duty, supply_v: f64) -> bool {
        self.step_within(dt_s, MAX_SUBSTEP_S, drive, duty, supply_v)
    }

    /// [`Plant::step`] with sub-steps of at most `max_substep_s` instead of [`MAX_SUBSTEP_S`] (the event engine
    /// takes whole stretches between commutations as one sub-step: `max_substep_s` = `dt_s`). At most
    /// [`MAX_STEP_S`] / `max_substep_s` + 1 sub-steps are taken; a non-positive or non-finite `max_substep_s`
    /// reads [`MAX_SUBSTEP_S`].
    pub fn step_within(
        &mut self,
        dt_s: f64,
        max_substep_s: f64,
        drive: BridgeDrive,
        duty: Duty,
        supply_v: f64,
    ) -> bool {
        let max_substep = if max_substep_s.is_finite() && max_substep_s > 0.0 {
            max_substep_s
        } else {
            MAX_SUBSTEP_S
        };
        let p = self.checked;
        self.evaluated = Cached(None);
        let supply = if supply_v.is_nan() {
            0.0
        } else {
            supply_v.clamp(0.0, MAX_SUPPLY_V)
        };
        let pwm_fraction = f64::from(duty.magnitude()) / f64::from(Duty::FULL);
        let ambient = finite_clamp(self.ambient_c, ABSOLUTE_ZERO_C, MAX_WINDING_C, DEFAULT_AMBIENT_C);
        if self.blocked {
            self.omega = 0.0;
        }

        let dt = if dt_s.is_finite() && dt_s > 0.0 {
            dt_s.min(MAX_STEP_S)
        } else {
            0.0
        };
        if dt > 0.0 {
            // At least 1 and at most MAX_STEP_S / max_substep (+1 for rounding) sub-steps.
            let substeps = (dt / max_substep).ceil().clamp(1.0, MAX_STEP_S / max_substep + 1.0);
            let h = dt / substeps;
            let decay = self.thermal_decay(&p, h);
            let mut remaining = substeps as u32;
            while remaining > 0 {
                remaining -= 1;
                self.substep(&p, h, decay, drive, pwm_fraction * supply, pwm_fraction, ambient);
            }
        } else {
            self.apply(self.electrical(&p, drive, pwm_fraction * supply, pwm_fraction));
        }

        self.halls_changed()
    }

    /// Whether the hall state differs from the one last reported, which it becomes.
    fn halls_changed(&mut self) -> bool {
        let hall = self.hall_state();
        let changed = hall != self.last_hall;
        self.last_hall = hall;
        changed
    }

    /// The event engine's look at the plant: the currents, torque and supply current at the present state with
    /// `drive` applied at `duty` on `supply_v`, as a zero [`Plant::step`] finds them; the next
    /// [`Plant::advance`] with the same drive and duty starts from this solution. Returns whether the halls
    /// changed without the rotor moving (a hall fault set or cleared).
    pub fn evaluate(&mut self, drive: BridgeDrive, duty: Duty, supply_v: f64) -> bool {
        if self.blocked {
            self.omega = 0.0;
        }
        let el = self.solve(drive, duty, supply_v);
        self.apply(el);
        self.evaluated = Cached(Some((drive, duty, el)));
        self.halls_changed()
    }

    /// The event engine's step: advance by `h_s` seconds in one sub-step (at most [`MAX_STEP_S`]; a non-finite or
    /// non-positive one advances nothing), starting from the electrical solution of the last
    /// [`Plant::evaluate`] if nothing moved since and the drive and duty are the same. The thermal decay comes
    /// from a short series (exact to the last bit for such steps) instead of `exp`. Returns whether the halls
    /// changed, as [`Plant::step`] does.
    pub fn advance(&mut self, h_s: f64, drive: BridgeDrive, duty: Duty, supply_v: f64) -> bool {
        let h = if h_s.is_finite() && h_s > 0.0 {
            h_s.min(MAX_STEP_S)
        } else {
            0.0
        };
        if h > 0.0 {
            if self.blocked {
                self.omega = 0.0;
            }
            let el = match self.evaluated.0 {
                Some((d, u, el)) if d == drive && u == duty => el,
                _ => self.solve(drive, duty, supply_v),
            };
            let p = self.checked;
            let ambient = finite_clamp(self.ambient_c, ABSOLUTE_ZERO_C, MAX_WINDING_C, DEFAULT_AMBIENT_C);
            let decay = short_exp(-h / (p.r_th * p.c_th));
            self.integrate(&p, h, decay, el, ambient);
            self.evaluated = Cached(None);
        }
        self.halls_changed()
    }

    /// The event engine's reading of the winding temperature and the phase currents `h_s` seconds on, without moving
    /// the plant there: the temperature as [`Plant::advance`] would leave it (the copper loss of the present state
    /// held, solved exactly: the same as advancing), the currents as the present state draws them with `drive` at
    /// `duty` on `supply_v`.
    pub fn reading_after(&mut self, h_s: f64, drive: BridgeDrive, duty: Duty, supply_v: f64) -> (f64, [f64; 3]) {
        let el = match self.evaluated.0 {
            Some((d, u, el)) if d == drive && u == duty => el,
            _ => {
                let el = self.solve(drive, duty, supply_v);
                self.evaluated = Cached(Some((drive, duty, el)));
                el
            }
        };
        let current = el.currents;
        let h = if h_s.is_finite() && h_s > 0.0 {
            h_s.min(MAX_STEP_S)
        } else {
            return (self.winding_c, current);
        };
        let p = self.checked;
        let ambient = finite_clamp(self.ambient_c, ABSOLUTE_ZERO_C, MAX_WINDING_C, DEFAULT_AMBIENT_C);
        (
            self.winding_after(&p, short_exp(-h / (p.r_th * p.c_th)), el, ambient),
            current,
        )
    }

    /// The local mechanical time constant, s: how fast the speed settles at the present state under the drive of
    /// the last [`Plant::evaluate`] (the event engine looks ahead a fraction of it). None before an evaluation.
    pub fn time_constant(&self) -> Option<f64> {
        let (_, _, el) = self.evaluated.0?;
        let p = self.checked;
        let slope = 2.0 * p.prop_k * self.omega.abs() + p.friction - el.damping;
        let tau = p.inertia / slope;
        (tau.is_finite() && tau > 0.0).then_some(tau)
    }

    /// The electrical solution for `drive` at `duty` on `supply_v` at the present state.
    fn solve(&self, drive: BridgeDrive, duty: Duty, supply_v: f64) -> Electrical {
        let supply = if supply_v.is_nan() {
            0.0
        } else {
            supply_v.clamp(0.0, MAX_SUPPLY_V)
        };
        let pwm_fraction = f64::from(duty.magnitude()) / f64::from(Duty::FULL);
        self.electrical(&self.checked, drive, pwm_fraction * supply, pwm_fraction)
    }

    /// Seconds until the halls next change if the drive is held: the rotor reaching the next sector boundary in
    /// the direction it turns (or, at rest, is pushed), at its present speed and acceleration. None when they will
    /// not change by themselves: a hall fault holds them, the motor has none (brushed), the rotor is held, at rest
    /// with no torque, or slowing to turn back before the boundary (then the boundary behind it comes next, which a
    /// later look finds). Needs the currents and torque evaluated at the present state (any [`Plant::step`] leaves
    /// them so for a zero step).
    pub fn time_to_edge(&self) -> Option<f64> {
        if self.hall_fault.is_some() || self.blocked || self.params.brushed {
            return None;
        }
        let p = self.checked;
        let w = self.omega;
        let acceleration = (self.torque - (p.prop_k * w * w.abs() + p.friction * w)) / p.inertia;
        let direction = if w != 0.0 { w.signum() } else { acceleration.signum() };
        if w == 0.0 && acceleration == 0.0 {
            return None;
        }
        // Sector boundaries sit at 30 + 60 k electrical degrees.
        let into_sector = rem_euclid(self.electrical_deg() - 30.0, 60.0);
        let to_boundary_deg = if direction > 0.0 {
            60.0 - into_sector
        } else {
            into_sector
        };
        let pole_pairs = f64::from(self.params.pole_pairs.max(1));
        let distance = to_boundary_deg * (PI / 180.0) / pole_pairs;
        // distance = v t + a t^2 / 2 along the direction of travel.
        let (v, a) = (w.abs(), acceleration * direction);
        let discriminant = v * v + 2.0 * a * distance;
        // Negative (or NaN): it turns back first.
        if discriminant.is_nan() || discriminant < 0.0 {
            return None;
        }
        let denominator = v + discriminant.sqrt();
        let t = if denominator > 0.0 {
            2.0 * distance / denominator
        } else {
            0.0
        };
        t.is_finite().then_some(t)
    }

    /// The hall lines: `hall_fault` if set, else the state at the rotor's electrical angle (a brushed motor has
    /// none: its lines read their pull-ups).
    pub fn hall_state(&self) -> HallState {
        match self.hall_fault {
            Some(state) => state,
            None if self.params.brushed => HallState::from_bits(0b111),
            None => self.rotor_hall_state(),
        }
    }

    /// Signed mechanical speed, rpm (positive forward).
    pub fn rpm(&self) -> f64 {
        self.omega * 60.0 / TAU
    }

    /// Magnitude of the current in the driven phases (the largest phase current; for a Pwm-Low pair, the pair's
    /// current): what the current sense sees. 0 while coasting.
    pub fn phase_current_a(&self) -> f64 {
        self.currents.iter().fold(0.0, |max: f64, i| max.max(i.abs()))
    }

    /// The phase currents, A, positive into the motor, that `drive` at `duty` on `supply_v` draws at the present
    /// state, without moving the plant: period averages (the model has no PWM ripple).
    pub fn currents_with(&self, drive: BridgeDrive, duty: Duty, supply_v: f64) -> [f64; 3] {
        self.solve(drive, duty, supply_v).currents
    }

    /// Current drawn from the supply, signed: |duty| x the current of the Pwm phase(s), negative while the motor
    /// regenerates. For the battery model.
    pub fn supply_current_a(&self) -> f64 {
        self.supply_a
    }

    /// Winding temperature, deg C.
    pub fn winding_c(&self) -> f64 {
        self.winding_c
    }

    /// Electromagnetic torque of the motor, N m, positive forward (also while `blocked`: the rope holds it).
    #[allow(dead_code, reason = "part of the plant's interface; the bench need not read it")]
    pub fn torque_nm(&self) -> f64 {
        self.torque
    }

    /// The halls of the rotor itself, ignoring `hall_fault`.
    fn rotor_hall_state(&self) -> HallState {
        let millideg = self.electrical_deg() * 1000.0;
        // `as` saturates (NaN -> 0); electrical_deg is in [0, 360) anyway and hall_state_at wraps.
        hall_state_at(millideg as u32)
    }

    /// Electrical angle, degrees, in [0, 360).
    fn electrical_deg(&self) -> f64 {
        self.electrical_deg
    }

    /// Turn the rotor to `angle_rad` (in [0, 2 pi)).
    fn set_angle(&mut self, angle_rad: f64) {
        self.angle_rad = angle_rad;
        let pole_pairs = f64::from(self.params.pole_pairs.max(1));
        let deg = rem_euclid(pole_pairs * angle_rad, TAU) * (180.0 / PI);
        // rem_euclid may round up to exactly 360.
        self.electrical_deg = if deg.is_finite() && deg < 360.0 { deg } else { 0.0 };
    }

    /// How much of the winding's distance from its settling temperature is left after `h` seconds:
    /// `exp(-h / tau)`. The bench steps with one `h` all along, so the last value is kept.
    fn thermal_decay(&mut self, p: &CheckedParams, h: f64) -> f64 {
        let exponent = -h / (p.r_th * p.c_th);
        let (last, decay) = self.decay.0;
        if exponent.to_bits() == last.to_bits() {
            return decay;
        }
        let decay = exponent.exp();
        self.decay = Cached((exponent, decay));
        decay
    }

    /// One sub-step of `h` seconds (h > 0): electrical solution at the start, then speed, angle and temperature
    /// (`decay` is [`Plant::thermal_decay`] of `h`).
    #[allow(
        clippy::too_many_arguments,
        reason = "the sub-step's inputs, computed once per step by the caller"
    )]
    fn substep(
        &mut self,
        p: &CheckedParams,
        h: f64,
        decay: f64,
        drive: BridgeDrive,
        pwm_v: f64,
        pwm_fraction: f64,
        ambient: f64,
    ) {
        let el = self.electrical(p, drive, pwm_v, pwm_fraction);
        self.integrate(p, h, decay, el, ambient);
    }

    /// Speed, angle and temperature over `h` seconds from the electrical solution `el` at the start.
    fn integrate(&mut self, p: &CheckedParams, h: f64, decay: f64, el: Electrical, ambient: f64) {
        self.apply(el);

        if self.blocked {
            self.omega = 0.0;
        } else {
            let w = self.omega;
            let load = p.prop_k * w * w.abs() + p.friction * w;
            let load_slope = 2.0 * p.prop_k * w.abs() + p.friction;
            // Linearised implicit Euler: the denominator is at least the inertia, so no step overshoots.
            let next = w + h * (el.torque - load) / (p.inertia + h * (load_slope - el.damping));
            let next = if next.is_finite() {
                next.clamp(-MAX_OMEGA, MAX_OMEGA)
            } else {
                0.0
            };
            self.set_angle(wrap_angle(self.angle_rad + 0.5 * (w + next) * h));
            self.omega = next;
        }

        self.winding_c = self.winding_after(p, decay, el, ambient);
    }

    /// The winding temperature after a time whose `decay` is `exp(-h / tau)`, with the copper loss of `el`: the
    /// exact solution of the first-order thermal model with the loss held.
    fn winding_after(&self, p: &CheckedParams, decay: f64, el: Electrical, ambient: f64) -> f64 {
        let settled = ambient + el.copper_w * p.r_th;
        let next = settled + (self.winding_c - settled) * decay;
        if next.is_finite() {
            next.clamp(ABSOLUTE_ZERO_C, MAX_WINDING_C)
        } else {
            ambient
        }
    }

    fn apply(&mut self, el: Electrical) {
        self.currents = el.currents;
        self.supply_a = el.supply_a;
        self.torque = el.torque;
    }

    /// Phase currents, supply current, torque and copper loss for `drive` with `pwm_v` on the Pwm phases, at the
    /// present angle and speed.
    fn electrical(&self, p: &CheckedParams, drive: BridgeDrive, pwm_v: f64, pwm_fraction: f64) -> Electrical {
        if drive.iter().filter(|d| **d != PhaseDrive::Float).count() < 2 {
            // No current path.
            return Electrical::default();
        }
        let theta = self.electrical_deg();
        let shapes = if self.params.brushed {
            [1.0, -1.0, 0.0]
        } else {
            [emf_shape(theta), emf_shape(theta - 120.0), emf_shape(theta - 240.0)]
        };
        let speed_emf = p.ke * self.omega;
        // Terminal voltage of each connected phase minus its back-EMF; None for a floating phase.
        let driven = drive.map(|d| match d {
            PhaseDrive::Pwm => Some(pwm_v),
            PhaseDrive::Low => Some(0.0),
            PhaseDrive::Float => None,
        });
        let mut count = 0.0;
        let mut sum_drop = 0.0;
        let mut sum_f = 0.0;
        let mut sum_f2 = 0.0;
        for (v, f) in driven.iter().zip(shapes) {
            if let Some(v) = v {
                count += 1.0;
                sum_drop += v - speed_emf * f;
                sum_f += f;
                sum_f2 += f * f;
            }
        }
        if count < 2.0 {
            return Electrical::default();
        }
        let neutral = sum_drop / count;
        let mut el = Electrical::default();
        for ((current, v), f) in el.currents.iter_mut().zip(driven).zip(shapes) {
            if let Some(v) = v {
                *current = (v - speed_emf * f - neutral) / p.resistance;
            }
        }
        for ((current, d), f) in el.currents.iter().zip(drive).zip(shapes) {
            el.torque += p.ke * f * current;
            el.copper_w += p.resistance * current * current;
            if d == PhaseDrive::Pwm {
                el.supply_a += pwm_fraction * current;
            }
        }
        // T = (ke / R) f' P (v - ke w f) with P the projection that removes the mean over the connected phases.
        el.damping = -(p.ke * p.ke / p.resistance) * (sum_f2 - sum_f * sum_f / count).max(0.0);
        el
    }
}

/// Phase A's back-EMF for forward rotation at electrical angle `deg` (any value), in units of its plateau: +1 on
/// [30, 150), -1 on [210, 330), linear between (zero crossings at 0 and 180).
fn emf_shape(deg: f64) -> f64 {
    let t = rem_euclid(deg, 360.0);
    if t < 30.0 {
        t / 30.0
    } else if t < 150.0 {
        1.0
    } else if t < 210.0 {
        (180.0 - t) / 30.0
    } else if t < 330.0 {
        -1.0
    } else if t < 360.0 {
        (t - 360.0) / 30.0
    } else {
        // NaN, or rem_euclid rounding up to 360.
        0.0
    }
}

/// `x.rem_euclid(m)` for a finite `m > 0`, bit for bit, without the generic `fmod` it calls (a long loop over the
/// bits, the plant's largest cost). For `|x| < 256 m`, `|x| - q m` is found by subtracting `m 2^k` wherever it fits,
/// from the largest `k` down: each subtraction is exact (Sterbenz: `m 2^k <= r < m 2^(k+1)`), so the remainder is
/// exact, as `fmod`'s is. Anything else (NaN, infinities, far-out values) goes to the library.
fn rem_euclid(x: f64, m: f64) -> f64 {
    let a = x.abs();
    if a < m {
        // `fmod` returns x itself.
        return if x < 0.0 { x + m } else { x };
    }
    if a.is_nan() || a >= 256.0 * m {
        return x.rem_euclid(m);
    }
    let (mut r, mut k) = (a, m);
    while 2.0 * k <= a {
        k *= 2.0;
    }
    loop {
        if r >= k {
            r -= k;
        }
        if k <= m {
            break;
        }
        k *= 0.5;
    }
    // `fmod` keeps the sign of x; `rem_euclid` then lifts a negative remainder by m.
    let r = if x.is_sign_negative() { -r } else { r };
    if r < 0.0 { r + m } else { r }
}

/// `exp(x)` for the event engine's thermal decay: four terms of the series for `|x| <= 1e-3` (a sub-step of up to
/// 30 ms at the 30 s time constant; the next term is below 1e-17 of the result), the library beyond.
fn short_exp(x: f64) -> f64 {
    if x.abs() <= 1e-3 {
        1.0 + x * (1.0 + x * (0.5 + x * (1.0 / 6.0 + x * (1.0 / 24.0))))
    } else {
        x.exp()
    }
}

/// A value kept to save recomputing it: never part of what the plant is, so any two compare equal.
#[derive(Debug, Clone, Copy)]
struct Cached<T>(T);

impl<T> PartialEq for Cached<T> {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

/// A mechanical angle in [0, 2 pi); non-finite reads 0.
fn wrap_angle(rad: f64) -> f64 {
    let wrapped = rem_euclid(rad, TAU);
    if wrapped.is_finite() && wrapped < TAU {
        wrapped
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests;
