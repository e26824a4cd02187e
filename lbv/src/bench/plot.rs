//! Drawing a run's trace as a picture: a standalone SVG document (no external resources, no script) with the
//! speeds, currents, temperatures and faults of every thruster over time, and the run's events as markers.
//!
//! Layout, top to bottom: the title and a legend; the event labels; four panels sharing the time axis:
//! shaft speed (measured solid, ordered dashed, one colour per thruster), motor current, winding temperature
//! (with the overtemperature set and clear levels), and a status strip (per thruster one lane per fault bit,
//! hatched where the master sees the thruster offline; then the armed periods with the battery voltage).
//! Events are thin vertical lines across all panels; hovering one shows its full text.
//!
//! Long series are cut down to at most [`MAX_POINTS`] points by keeping the minimum and the maximum of each
//! bucket, so a one-sample spike survives. Values that are NaN or infinite are skipped. The output depends
//! on the trace and title only: the same trace gives the same bytes.

use std::fmt::Write as _;

use super::trace::{Event, Sample, ThrusterSample, Trace};

/// Most points drawn for one series; longer series are decimated by min/max per bucket.
pub const MAX_POINTS: usize = 2000;

/// Brushless full scale, rpm, either way (tmc-proto `Speed::FULL_SCALE_RPM`).
const FULL_SCALE_RPM: f64 = 4500.0;
/// Largest speed step on the wire (tmc-proto `Speed::MAX_STEP`).
const MAX_STEP: f64 = 102.0;
/// Overtemperature is set at this winding temperature, deg C (IDS 8.4).
const OVERTEMP_SET_C: f64 = 110.0;
/// Overtemperature clears below this winding temperature, deg C (IDS 8.4).
const OVERTEMP_CLEAR_C: f64 = 100.0;

/// The fault bits (tmc-proto `Faults`), their names and colours in the status strip.
const FAULTS: [(u8, &str, &str); 5] = [
    (0x01, "overtemp", "#e8590c"),
    (0x02, "stalled motor", "#c2255c"),
    (0x04, "hall sensor error", "#f2b705"),
    (0x08, "ground fault", "#5f3dc4"),
    (0x10, "water detect", "#1c7ed6"),
];

/// One colour per thruster (cycled beyond ten).
const PALETTE: [&str; 10] = [
    "#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf",
];

const WIDTH: f64 = 1200.0;
const LEFT: f64 = 84.0;
const RIGHT: f64 = 64.0;
const PLOT_W: f64 = WIDTH - LEFT - RIGHT;
const RPM_H: f64 = 210.0;
const CURRENT_H: f64 = 130.0;
const TEMP_H: f64 = 130.0;
const PANEL_GAP: f64 = 14.0;
const LANE_H: f64 = 5.0;
const ROW_H: f64 = LANE_H * 5.0 + 5.0;
const ARMED_H: f64 = 40.0;
const LABEL_ROW_H: f64 = 13.0;
const MAX_LABEL_ROWS: usize = 4;
const LABEL_CHARS: usize = 36;
/// Events closer than this share a label, px.
const GROUP_PX: f64 = 4.0;
/// Rough width of one character at the label font size, px.
const CHAR_W: f64 = 5.9;

const FONT: &str = "DejaVu Sans, Helvetica, Arial, sans-serif";
const GRID: &str = "#e9e9e9";
const FRAME: &str = "#b8b8b8";
const INK: &str = "#222";
const MUTED: &str = "#555";

/// Draw the trace as a standalone SVG document (no external resources, no JavaScript).
#[must_use]
pub fn svg(trace: &Trace, title: &str) -> String {
    let samples: Vec<&Sample> = trace.samples.iter().filter(|s| s.t.is_finite()).collect();
    if samples.is_empty() {
        return empty_svg(trace, title);
    }
    Plot::new(trace, &samples).render(title)
}

/// The document for a trace without samples: the title, "no samples" and the events as a list.
fn empty_svg(trace: &Trace, title: &str) -> String {
    let mut body = Svg::default();
    body.text(LEFT, 24.0, "start", "font-size=\"16\" font-weight=\"bold\"", title);
    body.text(
        WIDTH / 2.0,
        80.0,
        "middle",
        "font-size=\"20\" fill=\"#777\"",
        "no samples",
    );
    let mut y = 110.0;
    if !trace.events.is_empty() {
        body.text(LEFT, y, "start", "font-size=\"12\" font-weight=\"bold\"", "events:");
        y += 16.0;
        for event in trace.events.iter().take(40) {
            let line = format!("{} s  {}", fmt_time(event.t), one_line(&event.text, 120));
            body.text(LEFT, y, "start", "font-size=\"11\"", &line);
            y += 14.0;
        }
        if trace.events.len() > 40 {
            body.text(
                LEFT,
                y,
                "start",
                "font-size=\"11\" fill=\"#777\"",
                &format!("… {} more", trace.events.len() - 40),
            );
            y += 14.0;
        }
    }
    body.finish(y + 10.0)
}

/// The time axis shared by all panels.
#[derive(Debug, Clone, Copy)]
struct TimeFrame {
    t0: f64,
    t1: f64,
}

impl TimeFrame {
    fn x(&self, t: f64) -> f64 {
        let x = LEFT + (t - self.t0) / (self.t1 - self.t0) * PLOT_W;
        if x.is_finite() {
            x.clamp(LEFT, LEFT + PLOT_W)
        } else {
            LEFT
        }
    }
}

/// A value axis: its range, the tick values and how many decimals their labels get.
#[derive(Debug, Clone)]
struct Axis {
    lo: f64,
    hi: f64,
    ticks: Vec<f64>,
    decimals: usize,
}

/// Where a value panel sits and what it shows.
#[derive(Debug, Clone)]
struct Panel {
    top: f64,
    height: f64,
    axis: Axis,
}

impl Panel {
    fn y(&self, v: f64) -> f64 {
        let bottom = self.top + self.height;
        let y = bottom - (v - self.axis.lo) / (self.axis.hi - self.axis.lo) * self.height;
        if y.is_finite() {
            y.clamp(self.top, bottom)
        } else {
            bottom
        }
    }
}

/// Where an event's label goes.
#[derive(Debug, Clone)]
struct Label {
    row: usize,
    text: String,
    anchor_end: bool,
    /// How many events (from this one on) the label stands for.
    covers: usize,
}

/// Everything needed to draw one trace.
#[derive(Debug)]
struct Plot<'a> {
    samples: &'a [&'a Sample],
    events: Vec<&'a Event>,
    thrusters: usize,
    frame: TimeFrame,
    /// Non-finite values met (and skipped).
    skipped: usize,
    /// Whether any series was decimated.
    decimated: bool,
}

impl<'a> Plot<'a> {
    fn new(trace: &'a Trace, samples: &'a [&'a Sample]) -> Self {
        let mut events: Vec<&Event> = trace.events.iter().filter(|e| e.t.is_finite()).collect();
        events.sort_by(|a, b| a.t.total_cmp(&b.t));
        let thrusters = samples.iter().map(|s| s.thrusters.len()).max().unwrap_or(0);
        let mut range = Range::default();
        for t in samples.iter().map(|s| s.t).chain(events.iter().map(|e| e.t)) {
            range.add(t);
        }
        let (mut t0, mut t1) = range.get().unwrap_or((0.0, 1.0));
        if t1 - t0 <= 0.0 || !(t1 - t0).is_finite() {
            t0 -= 0.5;
            t1 += 0.5;
        }
        let skipped = (trace.samples.len() - samples.len())
            + (trace.events.len() - events.len())
            + samples
                .iter()
                .map(|s| {
                    usize::from(!s.battery_v.is_finite())
                        + s.thrusters
                            .iter()
                            .map(|th| {
                                [th.rpm, th.current_a, th.temperature_c]
                                    .iter()
                                    .filter(|v| !v.is_finite())
                                    .count()
                            })
                            .sum::<usize>()
                })
                .sum::<usize>();
        Plot {
            samples,
            events,
            thrusters,
            frame: TimeFrame { t0, t1 },
            skipped,
            decimated: false,
        }
    }

    /// The finite points (t, value) of one thruster's quantity, decimated.
    fn series(&mut self, k: usize, f: impl Fn(&ThrusterSample) -> f64) -> Vec<(f64, f64)> {
        let points: Vec<(f64, f64)> = self
            .samples
            .iter()
            .filter_map(|s| s.thrusters.get(k).map(|th| (s.t, f(th))))
            .filter(|(_, v)| v.is_finite())
            .collect();
        self.decimated |= points.len() > MAX_POINTS;
        decimate(&points, MAX_POINTS)
    }

    /// The time intervals where `on` holds, each sample lasting until the next one.
    fn runs(&self, on: impl Fn(&Sample) -> bool) -> Vec<(f64, f64)> {
        let mut runs: Vec<(f64, f64)> = Vec::new();
        let mut last_dt = 0.0;
        let mut open: Option<f64> = None;
        let mut iter = self.samples.iter().peekable();
        while let Some(s) = iter.next() {
            let end = match iter.peek() {
                Some(next) => {
                    last_dt = (next.t - s.t).max(0.0);
                    next.t
                }
                // The last sample lasts as long as the one before it; a lone sample to the edge of the plot.
                None if last_dt > 0.0 => s.t + last_dt,
                None => self.frame.t1,
            };
            if on(s) {
                let start = *open.get_or_insert(s.t);
                if iter.peek().is_none() {
                    runs.push((start, end));
                }
            } else if let Some(start) = open.take() {
                runs.push((start, s.t));
            }
        }
        runs
    }

    /// Runs in pixels: at least `min_w` wide, merged where less than a pixel apart.
    fn spans(&self, runs: &[(f64, f64)], min_w: f64) -> Vec<(f64, f64)> {
        let mut spans: Vec<(f64, f64)> = Vec::new();
        for &(a, b) in runs {
            let (mut x0, mut x1) = (self.frame.x(a), self.frame.x(b));
            if x1 - x0 < min_w {
                let mid = (x0 + x1) / 2.0;
                x0 = (mid - min_w / 2.0).max(LEFT);
                x1 = (x0 + min_w).min(LEFT + PLOT_W);
            }
            match spans.last_mut() {
                Some(last) if x0 - last.1 < 1.0 => last.1 = last.1.max(x1),
                _ => spans.push((x0, x1)),
            }
        }
        spans
    }

    fn render(mut self, title: &str) -> String {
        let mut out = Svg::default();
        let mut y = self.header(&mut out, title);

        let labels = self.place_labels();
        let rows = labels.iter().flatten().map(|l| l.row + 1).max().unwrap_or(0);
        let band_top = y;
        if rows > 0 {
            y += rows as f64 * LABEL_ROW_H + 4.0;
        }
        let plot_top = y;

        // Speed.
        let mut panel_rpm = Range::default();
        panel_rpm.add(0.0);
        let mut rpm = Vec::new();
        let mut ordered = Vec::new();
        for k in 0..self.thrusters {
            let measured = self.series(k, |th| th.rpm);
            let wanted = self.series(k, |th| f64::from(th.ordered_step) * FULL_SCALE_RPM / MAX_STEP);
            for &(_, v) in measured.iter().chain(&wanted) {
                panel_rpm.add(v);
            }
            rpm.push(measured);
            ordered.push(wanted);
        }
        let panel = Panel {
            top: y,
            height: RPM_H,
            axis: axis(panel_rpm, RPM_H, false),
        };
        self.panel_frame(&mut out, &panel, "speed (rpm)");
        if panel.axis.lo < 0.0 && panel.axis.hi > 0.0 {
            let y0 = panel.y(0.0);
            out.line(LEFT, y0, LEFT + PLOT_W, y0, "stroke=\"#9a9a9a\" stroke-width=\"0.8\"");
        }
        for (k, pts) in ordered.iter().enumerate() {
            let style = format!(
                "stroke=\"{}\" stroke-width=\"1.3\" stroke-dasharray=\"6 4\" stroke-opacity=\"0.85\"",
                colour(k)
            );
            self.draw_series(&mut out, &panel, "rpm-ordered", k, pts, &style, None);
        }
        for (k, pts) in rpm.iter().enumerate() {
            let style = format!("stroke=\"{}\" stroke-width=\"1.6\"", colour(k));
            self.draw_series(&mut out, &panel, "rpm", k, pts, &style, Some(colour(k)));
        }
        if rpm.iter().all(Vec::is_empty) {
            no_data(&mut out, &panel);
        }
        y += RPM_H + PANEL_GAP;

        // Current.
        let mut range = Range::default();
        range.add(0.0);
        let currents: Vec<Vec<(f64, f64)>> = (0..self.thrusters).map(|k| self.series(k, |th| th.current_a)).collect();
        for &(_, v) in currents.iter().flatten() {
            range.add(v);
        }
        let panel = Panel {
            top: y,
            height: CURRENT_H,
            axis: axis(range, CURRENT_H, true),
        };
        self.panel_frame(&mut out, &panel, "current (A)");
        for (k, pts) in currents.iter().enumerate() {
            let style = format!("stroke=\"{}\" stroke-width=\"1.4\"", colour(k));
            self.draw_series(&mut out, &panel, "current", k, pts, &style, Some(colour(k)));
        }
        if currents.iter().all(Vec::is_empty) {
            no_data(&mut out, &panel);
        }
        y += CURRENT_H + PANEL_GAP;

        // Temperature.
        let mut range = Range::default();
        range.add(OVERTEMP_SET_C);
        range.add(OVERTEMP_CLEAR_C);
        let temps: Vec<Vec<(f64, f64)>> = (0..self.thrusters)
            .map(|k| self.series(k, |th| th.temperature_c))
            .collect();
        for &(_, v) in temps.iter().flatten() {
            range.add(v);
        }
        let panel = Panel {
            top: y,
            height: TEMP_H,
            axis: axis(range, TEMP_H, false),
        };
        self.panel_frame(&mut out, &panel, "winding temp (°C)");
        // The overtemperature levels, labelled in the right margin (set above its line, clear below its own).
        for (level, label, colour, dy) in [
            (OVERTEMP_SET_C, "110 set", "#d9480f", -1.5),
            (OVERTEMP_CLEAR_C, "100 clear", "#e67700", 8.0),
        ] {
            let yl = panel.y(level);
            let style = format!("stroke=\"{colour}\" stroke-width=\"1\" stroke-dasharray=\"4 3\"");
            out.line(LEFT, yl, LEFT + PLOT_W + 3.0, yl, &style);
            out.text(
                LEFT + PLOT_W + 4.0,
                yl + dy,
                "start",
                &format!("font-size=\"9\" fill=\"{colour}\""),
                label,
            );
        }
        for (k, pts) in temps.iter().enumerate() {
            let style = format!("stroke=\"{}\" stroke-width=\"1.4\"", colour(k));
            self.draw_series(&mut out, &panel, "temp", k, pts, &style, Some(colour(k)));
        }
        if temps.iter().all(Vec::is_empty) {
            no_data(&mut out, &panel);
        }
        y += TEMP_H + PANEL_GAP;

        // Status strip.
        y = self.status_legend(&mut out, y);
        y = self.status_strip(&mut out, y);
        let plot_bottom = y;

        // Time axis below the strip.
        let ticks = time_ticks(self.frame.t0, self.frame.t1);
        for &t in &ticks.ticks {
            let x = self.frame.x(t);
            out.line(x, plot_bottom, x, plot_bottom + 4.0, &format!("stroke=\"{MUTED}\""));
            out.text(
                x,
                plot_bottom + 15.0,
                "middle",
                "font-size=\"10\" fill=\"#444\"",
                &fmt_tick(t, ticks.decimals),
            );
        }
        out.text(
            LEFT + PLOT_W / 2.0,
            plot_bottom + 30.0,
            "middle",
            "font-size=\"11\" fill=\"#444\"",
            "time (s)",
        );
        y = plot_bottom + 38.0;

        // Events over everything.
        self.events_layer(&mut out, &labels, band_top, plot_top, plot_bottom);

        // Footnotes.
        let mut notes = Vec::new();
        if self.decimated {
            notes.push(format!(
                "long series drawn as min/max per bucket (at most {MAX_POINTS} points each)"
            ));
        }
        if self.skipped > 0 {
            notes.push(format!("{} non-finite value(s) skipped", self.skipped));
        }
        let hidden = self.events.len() - labels.iter().flatten().map(|l| l.covers).sum::<usize>();
        if hidden > 0 {
            notes.push(format!(
                "{hidden} event label(s) hidden where events crowd; hover a marker for its text"
            ));
        }
        for note in &notes {
            y += 13.0;
            out.text(LEFT, y, "start", "font-size=\"10\" fill=\"#777\"", note);
        }
        out.finish(y + 10.0)
    }

    /// Title, summary and thruster legend; returns the y below them.
    fn header(&self, out: &mut Svg, title: &str) -> f64 {
        out.text(
            LEFT,
            24.0,
            "start",
            &format!("font-size=\"16\" font-weight=\"bold\" fill=\"{INK}\""),
            title,
        );
        let summary = format!(
            "{} thruster{} · {} sample{} · {} event{} · {}",
            self.thrusters,
            plural(self.thrusters),
            self.samples.len(),
            plural(self.samples.len()),
            self.events.len(),
            plural(self.events.len()),
            time_span(self.samples),
        );
        out.text(WIDTH - RIGHT, 24.0, "end", "font-size=\"11\" fill=\"#666\"", &summary);

        let mut items: Vec<(f64, String)> = Vec::new();
        for k in 0..self.thrusters {
            items.push((52.0, format!("T{}", k + 1)));
        }
        let mut x = LEFT;
        let mut y = 44.0;
        for (k, (w, name)) in items.iter().enumerate() {
            if x + w > WIDTH - RIGHT {
                x = LEFT;
                y += 16.0;
            }
            out.line(
                x,
                y - 4.0,
                x + 18.0,
                y - 4.0,
                &format!("stroke=\"{}\" stroke-width=\"3\"", colour(k)),
            );
            out.text(x + 22.0, y, "start", "font-size=\"11\" font-weight=\"bold\"", name);
            x += w;
        }
        // Line styles.
        let explain = 300.0;
        if x + explain > WIDTH - RIGHT {
            x = LEFT;
            y += 16.0;
        } else {
            x += 14.0;
        }
        out.line(x, y - 4.0, x + 22.0, y - 4.0, "stroke=\"#666\" stroke-width=\"1.6\"");
        out.text(x + 26.0, y, "start", "font-size=\"11\" fill=\"#444\"", "measured");
        x += 90.0;
        out.line(
            x,
            y - 4.0,
            x + 22.0,
            y - 4.0,
            "stroke=\"#666\" stroke-width=\"1.3\" stroke-dasharray=\"6 4\"",
        );
        out.text(
            x + 26.0,
            y,
            "start",
            "font-size=\"11\" fill=\"#444\"",
            "ordered (step × 4500/102)",
        );
        y + 10.0
    }

    /// Frame, grid, ticks and the axis title of a value panel.
    fn panel_frame(&self, out: &mut Svg, panel: &Panel, name: &str) {
        let bottom = panel.top + panel.height;
        out.rect(LEFT, panel.top, PLOT_W, panel.height, "fill=\"#fff\"");
        for &v in &panel.axis.ticks {
            let y = panel.y(v);
            out.line(LEFT, y, LEFT + PLOT_W, y, &format!("stroke=\"{GRID}\""));
            out.line(LEFT - 4.0, y, LEFT, y, &format!("stroke=\"{MUTED}\""));
            out.text(
                LEFT - 6.0,
                y + 3.5,
                "end",
                "font-size=\"10\" fill=\"#444\"",
                &fmt_tick(v, panel.axis.decimals),
            );
        }
        self.time_grid(out, panel.top, bottom);
        out.rect(
            LEFT,
            panel.top,
            PLOT_W,
            panel.height,
            &format!("fill=\"none\" stroke=\"{FRAME}\""),
        );
        let cy = panel.top + panel.height / 2.0;
        let _ = writeln!(
            out.0,
            "<text transform=\"translate(16 {}) rotate(-90)\" text-anchor=\"middle\" font-size=\"11\" fill=\"#444\">{}</text>",
            num(cy),
            escape(name)
        );
    }

    /// Vertical grid lines at the time ticks.
    fn time_grid(&self, out: &mut Svg, top: f64, bottom: f64) {
        let ticks = time_ticks(self.frame.t0, self.frame.t1);
        for &t in &ticks.ticks {
            let x = self.frame.x(t);
            out.line(x, top, x, bottom, &format!("stroke=\"{GRID}\""));
        }
    }

    /// One polyline for thruster `k` (plus a dot of `dot` colour when it is a single point, which a line
    /// would not show).
    #[allow(clippy::too_many_arguments)]
    fn draw_series(
        &self,
        out: &mut Svg,
        panel: &Panel,
        class: &str,
        k: usize,
        pts: &[(f64, f64)],
        style: &str,
        dot: Option<&str>,
    ) {
        let _ = write!(
            out.0,
            "<polyline class=\"{class} t{}\" fill=\"none\" stroke-linejoin=\"round\" {style} points=\"",
            k + 1
        );
        for (i, &(t, v)) in pts.iter().enumerate() {
            if i > 0 {
                out.0.push(' ');
            }
            let _ = write!(out.0, "{},{}", num(self.frame.x(t)), num(panel.y(v)));
        }
        out.0.push_str("\"/>\n");
        if let ([(t, v)], Some(dot)) = (pts, dot) {
            let _ = writeln!(
                out.0,
                "<circle cx=\"{}\" cy=\"{}\" r=\"2.5\" fill=\"{dot}\"/>",
                num(self.frame.x(*t)),
                num(panel.y(*v)),
            );
        }
    }

    /// The legend line above the status strip; returns the y below it.
    fn status_legend(&self, out: &mut Svg, y: f64) -> f64 {
        let base = y + 11.0;
        let mut x = LEFT;
        out.text(
            x,
            base,
            "start",
            "font-size=\"11\" font-weight=\"bold\" fill=\"#444\"",
            "status:",
        );
        x += 48.0;
        for (_, name, colour) in FAULTS {
            out.rect(x, base - 8.0, 14.0, 8.0, &format!("fill=\"{colour}\""));
            out.text(x + 18.0, base, "start", "font-size=\"11\" fill=\"#333\"", name);
            x += 18.0 + name.chars().count() as f64 * 6.0 + 18.0;
        }
        out.rect(
            x,
            base - 9.0,
            14.0,
            10.0,
            "fill=\"url(#offline)\" stroke=\"#999\" stroke-width=\"0.5\"",
        );
        out.text(x + 18.0, base, "start", "font-size=\"11\" fill=\"#333\"", "offline");
        x += 18.0 + 7.0 * 6.0 + 18.0;
        out.rect(x, base - 9.0, 14.0, 10.0, "fill=\"#c3e6cb\"");
        out.text(x + 18.0, base, "start", "font-size=\"11\" fill=\"#333\"", "armed");
        x += 18.0 + 5.0 * 6.0 + 18.0;
        out.line(
            x,
            base - 4.0,
            x + 18.0,
            base - 4.0,
            "stroke=\"#333\" stroke-width=\"1.3\"",
        );
        out.text(x + 22.0, base, "start", "font-size=\"11\" fill=\"#333\"", "battery (V)");
        y + 17.0
    }

    /// Per thruster a row of fault lanes, then the armed/battery row; returns the y below.
    fn status_strip(&self, out: &mut Svg, top: f64) -> f64 {
        let mut y = top;
        for k in 0..self.thrusters {
            out.rect(LEFT, y, PLOT_W, ROW_H, "fill=\"#f7f7f7\"");
            let offline = self.runs(|s| s.thrusters.get(k).is_some_and(|th| !th.online));
            for (x0, x1) in self.spans(&offline, 1.5) {
                out.rect_class("offline", x0, y, x1 - x0, ROW_H, "fill=\"url(#offline)\"");
            }
            for (j, (bit, name, colour)) in FAULTS.iter().enumerate() {
                let runs = self.runs(|s| s.thrusters.get(k).is_some_and(|th| th.faults & bit != 0));
                let lane = y + 2.5 + j as f64 * LANE_H;
                for (x0, x1) in self.spans(&runs, 2.0) {
                    // A tint over the whole row makes a fault stand out; the lane says which one.
                    out.rect(
                        x0,
                        y,
                        x1 - x0,
                        ROW_H,
                        &format!("fill=\"{colour}\" fill-opacity=\"0.16\""),
                    );
                    let _ = writeln!(
                        out.0,
                        "<rect class=\"fault\" x=\"{}\" y=\"{}\" width=\"{}\" height=\"{}\" fill=\"{colour}\"><title>T{} {}</title></rect>",
                        num(x0),
                        num(lane),
                        num(x1 - x0),
                        num(LANE_H - 0.5),
                        k + 1,
                        name
                    );
                }
            }
            out.line(
                LEFT,
                y + ROW_H,
                LEFT + PLOT_W,
                y + ROW_H,
                "stroke=\"#fff\" stroke-width=\"1\"",
            );
            out.text(
                LEFT - 6.0,
                y + ROW_H / 2.0 + 4.0,
                "end",
                &format!("font-size=\"11\" font-weight=\"bold\" fill=\"{}\"", colour(k)),
                &format!("T{}", k + 1),
            );
            y += ROW_H;
        }

        // Armed periods and battery voltage.
        out.rect(LEFT, y, PLOT_W, ARMED_H, "fill=\"#f7f7f7\"");
        let armed = self.runs(|s| s.armed);
        for (x0, x1) in self.spans(&armed, 1.5) {
            out.rect_class("armed", x0, y, x1 - x0, ARMED_H, "fill=\"#c3e6cb\"");
        }
        let battery: Vec<(f64, f64)> = self
            .samples
            .iter()
            .map(|s| (s.t, s.battery_v))
            .filter(|(_, v)| v.is_finite())
            .collect();
        let battery = decimate(&battery, MAX_POINTS);
        let mut range = Range::default();
        for &(_, v) in &battery {
            range.add(v);
        }
        if let Some((lo, hi)) = range.get() {
            let (lo, hi) = if hi - lo < 0.1 {
                (lo - 0.05, hi + 0.05)
            } else {
                (lo, hi)
            };
            let row = Panel {
                top: y + 5.0,
                height: ARMED_H - 10.0,
                axis: Axis {
                    lo,
                    hi,
                    ticks: Vec::new(),
                    decimals: 1,
                },
            };
            let style = "stroke=\"#333\" stroke-width=\"1.3\"";
            self.draw_series(out, &row, "battery", 0, &battery, style, Some("#333"));
            out.text(
                LEFT + PLOT_W + 4.0,
                y + 9.0,
                "start",
                "font-size=\"10\" fill=\"#333\"",
                &format!("{hi:.2} V"),
            );
            out.text(
                LEFT + PLOT_W + 4.0,
                y + ARMED_H - 2.0,
                "start",
                "font-size=\"10\" fill=\"#333\"",
                &format!("{lo:.2} V"),
            );
        }
        out.text(
            LEFT - 6.0,
            y + 16.0,
            "end",
            "font-size=\"10\" fill=\"#2b8a3e\"",
            "armed",
        );
        out.text(LEFT - 6.0, y + 29.0, "end", "font-size=\"10\" fill=\"#333\"", "battery");
        y += ARMED_H;
        self.time_grid_over_strip(out, top, y);
        out.rect(LEFT, top, PLOT_W, y - top, &format!("fill=\"none\" stroke=\"{FRAME}\""));
        y
    }

    /// Faint time grid lines over the strip (drawn over the bars, so they stay visible).
    fn time_grid_over_strip(&self, out: &mut Svg, top: f64, bottom: f64) {
        let ticks = time_ticks(self.frame.t0, self.frame.t1);
        for &t in &ticks.ticks {
            let x = self.frame.x(t);
            out.line(x, top, x, bottom, "stroke=\"#fff\" stroke-opacity=\"0.5\"");
        }
    }

    /// Decide each event's label. Events within [`GROUP_PX`] of each other share one label, the first one's
    /// text with "(+N)"; each label goes in the first of [`MAX_LABEL_ROWS`] rows where it overlaps nothing. The
    /// result lines up with `self.events`: `None` for an event in another's group, or whose label found no room
    /// (its marker stays, with its text on hover).
    fn place_labels(&self) -> Vec<Option<Label>> {
        let mut rows: Vec<Vec<(f64, f64)>> = vec![Vec::new(); MAX_LABEL_ROWS];
        let mut labels: Vec<Option<Label>> = Vec::with_capacity(self.events.len());
        let xs: Vec<f64> = self.events.iter().map(|e| self.frame.x(e.t)).collect();
        let mut i = 0;
        while let Some(&x) = xs.get(i) {
            let group = xs
                .iter()
                .skip(i)
                .take_while(|&&other| other - x <= GROUP_PX)
                .count()
                .max(1);
            let text = self.events.get(i).map_or(String::new(), |event| {
                if group > 1 {
                    let more = format!(" (+{})", group - 1);
                    let first = one_line(&event.text, LABEL_CHARS.saturating_sub(more.chars().count()).max(8));
                    first + &more
                } else {
                    one_line(&event.text, LABEL_CHARS)
                }
            });
            let w = text.chars().count() as f64 * CHAR_W + 6.0;
            let anchor_end = x + w > WIDTH - RIGHT;
            let span = if anchor_end { (x - w, x + 1.0) } else { (x - 1.0, x + w) };
            let free = rows
                .iter()
                .position(|row| row.iter().all(|&(a, b)| span.1 + 3.0 < a || span.0 > b + 3.0));
            labels.push(free.map(|row| {
                if let Some(taken) = rows.get_mut(row) {
                    taken.push(span);
                }
                Label {
                    row,
                    text,
                    anchor_end,
                    covers: group,
                }
            }));
            labels.extend(std::iter::repeat_n(None, group - 1));
            i += group;
        }
        labels
    }

    /// Event markers across all panels, with their labels in the band above.
    fn events_layer(&self, out: &mut Svg, labels: &[Option<Label>], band_top: f64, plot_top: f64, plot_bottom: f64) {
        out.0.push_str("<g class=\"events\">\n");
        let mut in_group = 0;
        for (i, (event, label)) in self.events.iter().zip(labels).enumerate() {
            let x = self.frame.x(event.t);
            // A shared label's marker tells every event of its group on hover.
            let covers = label.as_ref().map_or(1, |l| l.covers);
            let tooltip: Vec<String> = self
                .events
                .iter()
                .skip(i)
                .take(covers)
                .map(|e| format!("{} s: {}", fmt_time(e.t), e.text))
                .collect();
            let _ = write!(
                out.0,
                "<g class=\"event\"><title>{}</title>",
                escape(&tooltip.join("\n"))
            );
            let grouped = in_group > 0;
            in_group = if covers > 1 {
                covers - 1
            } else {
                in_group.saturating_sub(1)
            };
            let line_top = match label {
                Some(l) => band_top + l.row as f64 * LABEL_ROW_H + 3.0,
                None => plot_top,
            };
            out.line(
                x,
                line_top,
                x,
                plot_bottom,
                "stroke=\"#343a40\" stroke-opacity=\"0.55\" stroke-width=\"1\"",
            );
            // A wider invisible line makes the marker easy to hover (the group's first one only, so that it
            // is the one to answer).
            if !grouped {
                out.line(
                    x,
                    line_top,
                    x,
                    plot_bottom,
                    "stroke=\"#000\" stroke-opacity=\"0\" stroke-width=\"6\"",
                );
            }
            if let Some(l) = label {
                let base = band_top + (l.row + 1) as f64 * LABEL_ROW_H - 2.0;
                let (tx, anchor) = if l.anchor_end {
                    (x - 3.0, "end")
                } else {
                    (x + 3.0, "start")
                };
                out.text(tx, base, anchor, "font-size=\"10\" fill=\"#343a40\"", &l.text);
            }
            out.0.push_str("</g>\n");
        }
        out.0.push_str("</g>\n");
    }
}

/// "no data" in the middle of a panel.
fn no_data(out: &mut Svg, panel: &Panel) {
    out.text(
        LEFT + PLOT_W / 2.0,
        panel.top + panel.height / 2.0 + 4.0,
        "middle",
        "font-size=\"12\" fill=\"#999\"",
        "no data",
    );
}

/// The smallest and largest finite value seen.
#[derive(Debug, Clone, Copy, Default)]
struct Range {
    lo: Option<f64>,
    hi: Option<f64>,
}

impl Range {
    fn add(&mut self, v: f64) {
        if v.is_finite() {
            self.lo = Some(self.lo.map_or(v, |lo| lo.min(v)));
            self.hi = Some(self.hi.map_or(v, |hi| hi.max(v)));
        }
    }

    fn get(&self) -> Option<(f64, f64)> {
        self.lo.zip(self.hi)
    }
}

/// A value axis covering `range`, rounded out to a nice step: the least wasted range with 3 to one per 25 px
/// intervals (fewer when the panel is too small for 3).
fn axis(range: Range, height: f64, nonneg: bool) -> Axis {
    let (mut lo, mut hi) = range.get().unwrap_or((0.0, 1.0));
    if nonneg && lo == 0.0 && hi == 0.0 {
        hi = 1.0;
    } else if hi - lo <= 0.0 {
        let pad = (lo.abs() * 0.1).max(1.0);
        lo -= pad;
        hi += pad;
    }
    if !(hi - lo).is_finite() {
        // Absurd magnitudes: keep going without ticks rather than loop over them.
        return Axis {
            lo: -1.0,
            hi: 1.0,
            ticks: vec![-1.0, 0.0, 1.0],
            decimals: 0,
        };
    }
    let max_intervals = (height / 25.0).floor().max(2.0);
    let min_intervals = max_intervals.min(3.0);
    let mut best: Option<(f64, f64, f64)> = None;
    for step in candidate_steps((hi - lo) / max_intervals) {
        let a = (lo / step).floor() * step;
        let b = (hi / step).ceil() * step;
        let count = ((b - a) / step).round();
        if (min_intervals..=max_intervals).contains(&count)
            && best.is_none_or(|(ba, bb, _)| b - a < bb - ba - step * 1e-9)
        {
            best = Some((a, b, step));
        }
    }
    let Some((lo, hi, step)) = best else {
        return Axis {
            lo,
            hi,
            ticks: vec![lo, hi],
            decimals: decimals_for(hi - lo),
        };
    };
    Axis {
        lo,
        hi,
        ticks: ticks_between(lo, hi, step),
        decimals: decimals_for(step),
    }
}

/// Time ticks: nice multiples inside [t0, t1], about one per 80 px.
fn time_ticks(t0: f64, t1: f64) -> Axis {
    let max_ticks = (PLOT_W / 80.0).floor();
    let span = t1 - t0;
    let step = candidate_steps(span / max_ticks)
        .into_iter()
        .find(|step| (span / step).floor() <= max_ticks)
        .unwrap_or(span);
    if step.is_nan() || step <= 0.0 || !step.is_finite() {
        return Axis {
            lo: t0,
            hi: t1,
            ticks: Vec::new(),
            decimals: 0,
        };
    }
    let first = (t0 / step - 1e-9).ceil() * step;
    let last = (t1 / step + 1e-9).floor() * step;
    Axis {
        lo: t0,
        hi: t1,
        ticks: ticks_between(first, last, step),
        decimals: decimals_for(step),
    }
}

/// 1, 2, 2.5 and 5 times powers of ten from a bit under `raw` upwards, smallest first.
fn candidate_steps(raw: f64) -> Vec<f64> {
    if raw.is_nan() || raw <= 0.0 || !raw.is_finite() {
        return Vec::new();
    }
    let exp = raw.log10().floor() as i32;
    let mut steps = Vec::new();
    for e in exp - 1..=exp + 1 {
        let mag = 10f64.powi(e);
        for m in [1.0, 2.0, 2.5, 5.0] {
            let step = m * mag;
            if step > 0.0 && step.is_finite() {
                steps.push(step);
            }
        }
    }
    steps
}

/// lo, lo + step, … up to hi (at most 200 of them).
fn ticks_between(lo: f64, hi: f64, step: f64) -> Vec<f64> {
    let count = ((hi - lo) / step).round();
    if !count.is_finite() || count < 0.0 {
        return Vec::new();
    }
    let count = count.min(200.0) as usize;
    (0..=count)
        .map(|i| {
            let v = lo + i as f64 * step;
            // Snap what should be zero to zero (and never print "-0").
            if v.abs() < step * 1e-6 { 0.0 } else { v }
        })
        .collect()
}

/// Decimals needed to print multiples of `step` exactly.
fn decimals_for(step: f64) -> usize {
    (0..=6)
        .find(|&d| {
            let scaled = step * 10f64.powi(d);
            (scaled - scaled.round()).abs() < 1e-6 * scaled.abs().max(1.0)
        })
        .map_or(6, |d| d as usize)
}

fn fmt_tick(v: f64, decimals: usize) -> String {
    let s = format!("{v:.decimals$}");
    if s.trim_start_matches('-').chars().all(|c| c == '0' || c == '.') {
        s.trim_start_matches('-').to_string()
    } else {
        s
    }
}

/// "0–20 s", or "t = 3 s" for a single instant.
fn time_span(samples: &[&Sample]) -> String {
    let first = samples.first().map_or(0.0, |s| s.t);
    let last = samples.last().map_or(0.0, |s| s.t);
    if first == last {
        format!("t = {} s", fmt_time(first))
    } else {
        format!("{}–{} s", fmt_time(first), fmt_time(last))
    }
}

fn fmt_time(t: f64) -> String {
    let s = format!("{t:.3}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

/// Cut a series down to at most `max` points: the first and last points, and per bucket of consecutive points
/// its minimum and its maximum in their original order, so that a spike of a single sample survives.
fn decimate(points: &[(f64, f64)], max: usize) -> Vec<(f64, f64)> {
    if points.len() <= max || max < 4 {
        return points.to_vec();
    }
    let n = points.len();
    let buckets = (max - 2) / 2;
    let mut out = Vec::with_capacity(max);
    let mut last: Option<usize> = None;
    let mut push = |i: usize, out: &mut Vec<(f64, f64)>| {
        if last.is_none_or(|l| i > l)
            && let Some(&p) = points.get(i)
        {
            out.push(p);
            last = Some(i);
        }
    };
    push(0, &mut out);
    for b in 0..buckets {
        let (start, end) = (b * n / buckets, (b + 1) * n / buckets);
        let Some(chunk) = points.get(start..end) else { continue };
        let mut lo = 0;
        let mut hi = 0;
        for (i, p) in chunk.iter().enumerate() {
            if chunk.get(lo).is_some_and(|q| p.1 < q.1) {
                lo = i;
            }
            if chunk.get(hi).is_some_and(|q| p.1 > q.1) {
                hi = i;
            }
        }
        push(start + lo.min(hi), &mut out);
        push(start + lo.max(hi), &mut out);
    }
    push(n - 1, &mut out);
    out
}

/// A coordinate with at most one decimal, and no "-0".
fn num(v: f64) -> String {
    let r = (v * 10.0).round() / 10.0;
    if r == 0.0 || !r.is_finite() {
        "0".to_string()
    } else {
        format!("{r}")
    }
}

fn colour(k: usize) -> &'static str {
    PALETTE.get(k % PALETTE.len()).copied().unwrap_or("#000")
}

fn plural(n: usize) -> &'static str {
    if n == 1 { "" } else { "s" }
}

/// Text on one line (whitespace runs collapsed), cut to `max` characters with an ellipsis.
fn one_line(text: &str, max: usize) -> String {
    let words: Vec<&str> = text.split_whitespace().collect();
    let line = words.join(" ");
    if line.chars().count() <= max {
        line
    } else {
        let mut cut: String = line.chars().take(max.saturating_sub(1)).collect();
        cut.push('…');
        cut
    }
}

/// Text made safe for XML content and attribute values; characters XML 1.0 forbids become U+FFFD.
fn escape(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&apos;"),
            '\t' | '\n' | '\r' => out.push(c),
            c if (c as u32) < 0x20 || c == '\u{FFFE}' || c == '\u{FFFF}' => out.push('\u{FFFD}'),
            c => out.push(c),
        }
    }
    out
}

/// The document being written.
#[derive(Debug, Default)]
struct Svg(String);

impl Svg {
    fn line(&mut self, x1: f64, y1: f64, x2: f64, y2: f64, style: &str) {
        let _ = writeln!(
            self.0,
            "<line x1=\"{}\" y1=\"{}\" x2=\"{}\" y2=\"{}\" {style}/>",
            num(x1),
            num(y1),
            num(x2),
            num(y2)
        );
    }

    fn rect(&mut self, x: f64, y: f64, w: f64, h: f64, style: &str) {
        let _ = writeln!(
            self.0,
            "<rect x=\"{}\" y=\"{}\" width=\"{}\" height=\"{}\" {style}/>",
            num(x),
            num(y),
            num(w),
            num(h)
        );
    }

    fn rect_class(&mut self, class: &str, x: f64, y: f64, w: f64, h: f64, style: &str) {
        let _ = writeln!(
            self.0,
            "<rect class=\"{class}\" x=\"{}\" y=\"{}\" width=\"{}\" height=\"{}\" {style}/>",
            num(x),
            num(y),
            num(w),
            num(h)
        );
    }

    fn text(&mut self, x: f64, y: f64, anchor: &str, style: &str, content: &str) {
        let _ = writeln!(
            self.0,
            "<text x=\"{}\" y=\"{}\" text-anchor=\"{anchor}\" {style}>{}</text>",
            num(x),
            num(y),
            escape(content)
        );
    }

    /// The whole document around the body drawn so far.
    fn finish(self, height: f64) -> String {
        let h = num(height.ceil());
        let w = num(WIDTH);
        let mut doc = String::with_capacity(self.0.len() + 1024);
        let _ = write!(
            doc,
            "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n\
             <svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"{h}\" viewBox=\"0 0 {w} {h}\" \
             font-family=\"{FONT}\" fill=\"{INK}\">\n\
             <defs><pattern id=\"offline\" patternUnits=\"userSpaceOnUse\" width=\"6\" height=\"6\" \
             patternTransform=\"rotate(45)\"><rect width=\"6\" height=\"6\" fill=\"#dcdcdc\"/>\
             <line x1=\"0\" y1=\"0\" x2=\"0\" y2=\"6\" stroke=\"#9a9a9a\" stroke-width=\"2.5\"/></pattern></defs>\n\
             <rect width=\"100%\" height=\"100%\" fill=\"#fff\"/>\n"
        );
        doc.push_str(&self.0);
        doc.push_str("</svg>\n");
        doc
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small well-formedness check: one root element, tags balanced and properly nested, attributes
    /// quoted and unique, and every `&` in text and attribute values starting a known entity.
    fn check_xml(doc: &str) -> Result<usize, String> {
        fn check_text(text: &str) -> Result<(), String> {
            let mut rest = text;
            while let Some(i) = rest.find('&') {
                rest = &rest[i + 1..];
                let end = rest
                    .find(';')
                    .ok_or_else(|| format!("bare & before {:?}", &rest[..rest.len().min(20)]))?;
                let entity = &rest[..end];
                let ok = matches!(entity, "amp" | "lt" | "gt" | "quot" | "apos")
                    || entity
                        .strip_prefix("#x")
                        .is_some_and(|h| !h.is_empty() && h.chars().all(|c| c.is_ascii_hexdigit()))
                    || entity
                        .strip_prefix('#')
                        .is_some_and(|d| !d.is_empty() && d.chars().all(|c| c.is_ascii_digit()));
                if !ok {
                    return Err(format!("unknown entity &{entity};"));
                }
            }
            if text
                .chars()
                .any(|c| (c as u32) < 0x20 && !matches!(c, '\t' | '\n' | '\r'))
            {
                return Err("control character".to_string());
            }
            Ok(())
        }
        fn check_name(name: &str) -> Result<(), String> {
            let ok = name.chars().next().is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
                && name
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | ':' | '.'));
            if ok { Ok(()) } else { Err(format!("bad name {name:?}")) }
        }

        let mut rest = doc;
        if let Some(r) = rest.strip_prefix("<?xml") {
            let end = r.find("?>").ok_or("unclosed declaration")?;
            rest = &r[end + 2..];
        }
        let mut stack: Vec<&str> = Vec::new();
        let mut roots = 0;
        let mut elements = 0;
        loop {
            let Some(i) = rest.find('<') else {
                if !rest.trim().is_empty() && stack.is_empty() {
                    return Err("text after the root".to_string());
                }
                check_text(rest)?;
                break;
            };
            let text = &rest[..i];
            if stack.is_empty() && !text.trim().is_empty() {
                return Err(format!("text outside the root: {text:?}"));
            }
            check_text(text)?;
            rest = &rest[i..];
            if let Some(r) = rest.strip_prefix("<!--") {
                let end = r.find("-->").ok_or("unclosed comment")?;
                rest = &r[end + 3..];
                continue;
            }
            if let Some(r) = rest.strip_prefix("</") {
                let end = r.find('>').ok_or("unclosed end tag")?;
                let name = r[..end].trim_end();
                match stack.pop() {
                    Some(open) if open == name => {}
                    other => return Err(format!("</{name}> closes {other:?}")),
                }
                rest = &r[end + 1..];
                continue;
            }
            let r = &rest[1..];
            let name_end = r
                .find(|c: char| c.is_whitespace() || c == '>' || c == '/')
                .ok_or("unclosed tag")?;
            let name = &r[..name_end];
            check_name(name)?;
            if stack.is_empty() {
                roots += 1;
            }
            elements += 1;
            let mut r = &r[name_end..];
            let mut attrs: Vec<&str> = Vec::new();
            loop {
                let trimmed = r.trim_start();
                let spaced = trimmed.len() < r.len();
                r = trimmed;
                if let Some(x) = r.strip_prefix("/>") {
                    rest = x;
                    break;
                }
                if let Some(x) = r.strip_prefix('>') {
                    stack.push(name);
                    rest = x;
                    break;
                }
                if !spaced {
                    return Err(format!("no space before attribute in <{name}>"));
                }
                let eq = r
                    .find('=')
                    .ok_or_else(|| format!("attribute without value in <{name}>"))?;
                let attr = r[..eq].trim_end();
                check_name(attr)?;
                if attrs.contains(&attr) {
                    return Err(format!("duplicate attribute {attr} in <{name}>"));
                }
                attrs.push(attr);
                let x = r[eq + 1..].trim_start();
                let quote = x
                    .chars()
                    .next()
                    .filter(|c| matches!(c, '"' | '\''))
                    .ok_or("unquoted attribute")?;
                let x = &x[1..];
                let close = x.find(quote).ok_or("unclosed attribute value")?;
                let value = &x[..close];
                if value.contains('<') {
                    return Err(format!("< in attribute {attr}"));
                }
                check_text(value)?;
                r = &x[close + 1..];
            }
        }
        if let Some(open) = stack.last() {
            return Err(format!("<{open}> never closed"));
        }
        if roots != 1 {
            return Err(format!("{roots} root elements"));
        }
        Ok(elements)
    }

    fn thruster(rpm: f64, current_a: f64, temperature_c: f64) -> ThrusterSample {
        ThrusterSample {
            rpm,
            current_a,
            temperature_c,
            faults: 0,
            online: true,
            ordered_step: 0,
        }
    }

    /// `n` thrusters over `seconds` at 100 Hz: a stall on T3 from 5 s, overtemp on T2, T6 offline for a while.
    fn demo(n: usize, seconds: f64) -> Trace {
        let mut samples = Vec::new();
        let mut i = 0;
        loop {
            let t = f64::from(i) * 0.01;
            if t > seconds + 1e-9 {
                break;
            }
            let thrusters = (0..n)
                .map(|k| {
                    let step = if t < 1.0 { 0 } else { 40 + 5 * k as i8 };
                    let stalled = k == 2 && t >= 5.0;
                    let rpm = if stalled {
                        0.0
                    } else {
                        f64::from(step) * FULL_SCALE_RPM / MAX_STEP
                    };
                    let temperature_c = if k == 1 { 40.0 + 6.0 * t } else { 40.0 + t };
                    let mut faults = 0;
                    if stalled {
                        faults |= 0x02;
                    }
                    if temperature_c > 110.0 {
                        faults |= 0x01;
                    }
                    ThrusterSample {
                        rpm,
                        current_a: if stalled { 18.0 } else { 3.0 },
                        temperature_c,
                        faults,
                        online: !(k == 5 && (12.0..13.0).contains(&t)),
                        ordered_step: step,
                    }
                })
                .collect();
            samples.push(Sample {
                t,
                thrusters,
                battery_v: 16.0 - t * 0.01,
                armed: t >= 1.0,
            });
            i += 1;
        }
        let events = vec![
            Event {
                t: 1.0,
                text: "armed".to_string(),
            },
            Event {
                t: 5.0,
                text: "inject: stall T3".to_string(),
            },
            Event {
                t: 5.1,
                text: "STATUSTEXT: T3 stalled motor".to_string(),
            },
        ];
        Trace { samples, events }
    }

    fn count(doc: &str, needle: &str) -> usize {
        doc.matches(needle).count()
    }

    /// The points of the first polyline whose class is `class`.
    fn points(doc: &str, class: &str) -> Vec<(f64, f64)> {
        let start = doc.find(&format!("<polyline class=\"{class}\"")).expect("polyline");
        let rest = &doc[start..];
        let p = rest.find("points=\"").expect("points") + 8;
        let end = rest[p..].find('"').expect("end of points");
        rest[p..p + end]
            .split(' ')
            .filter(|s| !s.is_empty())
            .map(|xy| {
                let (x, y) = xy.split_once(',').expect("x,y");
                (x.parse().expect("x"), y.parse().expect("y"))
            })
            .collect()
    }

    #[test]
    fn demo_is_well_formed_with_one_polyline_per_thruster_per_panel() {
        let doc = svg(&demo(6, 20.0), "demo");
        let elements = check_xml(&doc).expect("well-formed");
        assert!(elements > 100, "{elements} elements");
        assert!(doc.starts_with("<?xml"));
        for k in 1..=6 {
            for class in ["rpm", "rpm-ordered", "current", "temp"] {
                assert_eq!(
                    count(&doc, &format!("<polyline class=\"{class} t{k}\"")),
                    1,
                    "{class} t{k}"
                );
            }
            assert!(doc.contains(&format!(">T{k}</text>")), "legend T{k}");
        }
        assert_eq!(count(&doc, "<polyline class=\"rpm t7\""), 0);
        // The stall on T3 and the overtemp on T2 show as bars; T6 offline is hatched.
        assert!(doc.contains("<title>T3 stalled motor</title>"));
        assert!(doc.contains("<title>T2 overtemp</title>"));
        assert_eq!(count(&doc, "class=\"offline\""), 1);
        assert!(count(&doc, "class=\"armed\"") >= 1);
        // Three events, each a marker with its text on hover.
        assert_eq!(count(&doc, "<g class=\"event\">"), 3);
        // No script, no external references, no junk numbers.
        for bad in ["<script", "href", "NaN", "inf", "http://www.w3.org/1999/xlink"] {
            assert!(!doc.contains(bad), "{bad}");
        }
    }

    #[test]
    fn ordered_speed_is_step_times_full_scale() {
        let doc = svg(&demo(1, 2.0), "ordered");
        let ordered = points(&doc, "rpm-ordered t1");
        let measured = points(&doc, "rpm t1");
        // Measured speed follows the order in the demo: the same y for the same x.
        assert_eq!(ordered, measured);
    }

    #[test]
    fn text_is_escaped() {
        let mut trace = demo(2, 2.0);
        trace.events.push(Event {
            t: 1.5,
            text: "a <b> & \"c\" 'd' \u{1}".to_string(),
        });
        let doc = svg(&trace, "run <1> & \"2\"");
        check_xml(&doc).expect("well-formed");
        assert!(doc.contains("run &lt;1&gt; &amp; &quot;2&quot;"));
        assert!(doc.contains("a &lt;b&gt; &amp; &quot;c&quot; &apos;d&apos;"));
        assert!(!doc.contains("<b>"));
        assert!(!doc.contains('\u{1}'));
    }

    #[test]
    fn decimation_keeps_a_single_sample_spike() {
        let n = 10_000;
        let series: Vec<(f64, f64)> = (0..n)
            .map(|i| (f64::from(i), if i == 4321 { 50.0 } else { 1.0 }))
            .collect();
        let kept = decimate(&series, MAX_POINTS);
        assert!(kept.len() <= MAX_POINTS, "{}", kept.len());
        assert!(kept.contains(&(4321.0, 50.0)));
        assert_eq!(kept.first(), series.first());
        assert_eq!(kept.last(), series.last());
        assert!(kept.windows(2).all(|w| w[0].0 < w[1].0), "in time order");
        // A dip survives too.
        let series: Vec<(f64, f64)> = (0..n)
            .map(|i| (f64::from(i), if i == 77 { -5.0 } else { 1.0 }))
            .collect();
        assert!(decimate(&series, MAX_POINTS).contains(&(77.0, -5.0)));
        // Short series are left alone.
        assert_eq!(decimate(&series[..100], MAX_POINTS), series[..100].to_vec());

        // Through the whole drawing: 10 000 samples, one current spike.
        let samples = (0..n)
            .map(|i| Sample {
                t: f64::from(i) * 0.001,
                thrusters: vec![thruster(100.0, if i == 6543 { 40.0 } else { 2.0 }, 50.0)],
                battery_v: 16.0,
                armed: true,
            })
            .collect();
        let doc = svg(
            &Trace {
                samples,
                events: Vec::new(),
            },
            "spike",
        );
        check_xml(&doc).expect("well-formed");
        let current = points(&doc, "current t1");
        assert!(current.len() <= MAX_POINTS, "{}", current.len());
        let top = current.iter().map(|p| p.1).fold(f64::INFINITY, f64::min);
        let base = current.iter().map(|p| p.1).fold(f64::NEG_INFINITY, f64::max);
        assert!(base - top > 50.0, "the spike stands out: {top} vs {base}");
        assert!(doc.contains("min/max per bucket"));
    }

    #[test]
    fn empty_trace() {
        let doc = svg(&Trace::default(), "nothing <here>");
        check_xml(&doc).expect("well-formed");
        assert!(doc.contains("no samples"));
        assert!(doc.contains("nothing &lt;here&gt;"));
        let with_events = Trace {
            samples: Vec::new(),
            events: vec![Event {
                t: 0.5,
                text: "armed & ready".to_string(),
            }],
        };
        let doc = svg(&with_events, "events only");
        check_xml(&doc).expect("well-formed");
        assert!(doc.contains("no samples"));
        assert!(doc.contains("armed &amp; ready"));
    }

    #[test]
    fn single_sample() {
        let trace = Trace {
            samples: vec![Sample {
                t: 3.0,
                thrusters: vec![thruster(1200.0, 3.0, 40.0), thruster(-800.0, 2.0, 45.0)],
                battery_v: 16.0,
                armed: true,
            }],
            events: vec![Event {
                t: 3.0,
                text: "only".to_string(),
            }],
        };
        let doc = svg(&trace, "one");
        check_xml(&doc).expect("well-formed");
        for k in 1..=2 {
            for class in ["rpm", "current", "temp"] {
                assert_eq!(points(&doc, &format!("{class} t{k}")).len(), 1);
            }
        }
        // A dot for each measured point (3 panels x 2 thrusters) and the battery.
        assert_eq!(count(&doc, "<circle"), 7);
        assert!(!doc.contains("NaN"));
    }

    #[test]
    fn non_finite_values_are_skipped_and_zero_series_get_an_axis() {
        let samples = (0..50)
            .map(|i| {
                let mut th = thruster(0.0, 0.0, 0.0);
                if i == 10 {
                    th.rpm = f64::NAN;
                    th.current_a = f64::INFINITY;
                    th.temperature_c = f64::NEG_INFINITY;
                }
                Sample {
                    t: f64::from(i) * 0.1,
                    thrusters: vec![th],
                    battery_v: 0.0,
                    armed: false,
                }
            })
            .chain(std::iter::once(Sample {
                t: f64::NAN,
                ..Sample::default()
            }))
            .collect();
        let events = vec![Event {
            t: f64::INFINITY,
            text: "never".to_string(),
        }];
        let doc = svg(&Trace { samples, events }, "zeros");
        check_xml(&doc).expect("well-formed");
        assert_eq!(points(&doc, "rpm t1").len(), 49);
        assert_eq!(points(&doc, "current t1").len(), 49);
        assert_eq!(points(&doc, "temp t1").len(), 49);
        assert!(doc.contains("5 non-finite value(s) skipped"));
        for bad in ["NaN", "inf"] {
            assert!(!doc.contains(bad), "{bad}");
        }
        // All-zero speed: a symmetric axis around zero; all-zero current: 0..1.
        let rpm = axis(
            Range {
                lo: Some(0.0),
                hi: Some(0.0),
            },
            RPM_H,
            false,
        );
        assert!(rpm.lo < 0.0 && rpm.hi > 0.0 && rpm.ticks.contains(&0.0), "{rpm:?}");
        let current = axis(
            Range {
                lo: Some(0.0),
                hi: Some(0.0),
            },
            CURRENT_H,
            true,
        );
        assert_eq!((current.lo, current.hi), (0.0, 1.0));
        assert!(current.ticks.len() >= 3);
    }

    #[test]
    fn axes_have_round_steps() {
        let a = axis(
            Range {
                lo: Some(0.0),
                hi: Some(25.0),
            },
            CURRENT_H,
            true,
        );
        assert_eq!(a.ticks, vec![0.0, 5.0, 10.0, 15.0, 20.0, 25.0]);
        assert_eq!(a.decimals, 0);
        let a = axis(
            Range {
                lo: Some(-2647.0),
                hi: Some(3529.0),
            },
            RPM_H,
            false,
        );
        assert_eq!((a.lo, a.hi), (-3000.0, 4000.0));
        assert_eq!(fmt_tick(a.ticks[0], a.decimals), "-3000");
        let a = axis(
            Range {
                lo: Some(15.44),
                hi: Some(16.4),
            },
            TEMP_H,
            false,
        );
        assert!(a.lo <= 15.44 && a.hi >= 16.4 && a.decimals >= 1, "{a:?}");
        let t = time_ticks(0.0, 20.0);
        assert_eq!(t.ticks.first(), Some(&0.0));
        assert_eq!(t.ticks.last(), Some(&20.0));
        assert!(t.ticks.len() >= 5 && t.ticks.len() <= 14, "{:?}", t.ticks);
        let t = time_ticks(2.5, 3.5);
        assert!(t.ticks.iter().all(|&v| (2.5..=3.5).contains(&v)));
        assert_eq!(fmt_tick(-0.0, 1), "0.0");
        // Absurd ranges do not hang or panic.
        let a = axis(
            Range {
                lo: Some(-f64::MAX),
                hi: Some(f64::MAX),
            },
            RPM_H,
            false,
        );
        assert!(a.ticks.len() <= 201);
        assert!(time_ticks(-f64::MAX, f64::MAX).ticks.len() <= 201);
    }

    #[test]
    fn close_event_labels_are_staggered_and_crowds_hidden() {
        let mut trace = demo(1, 10.0);
        // 12 events about 10 px apart: four rows of labels, then no room.
        trace.events = (0..12)
            .map(|i| Event {
                t: 4.0 + f64::from(i) * 0.1,
                text: format!("event {i} with a long text to cut it short"),
            })
            .collect();
        let plot_samples: Vec<&Sample> = trace.samples.iter().collect();
        let plot = Plot::new(&trace, &plot_samples);
        let labels = plot.place_labels();
        assert_eq!(labels.len(), 12);
        let rows: Vec<usize> = labels.iter().flatten().map(|l| l.row).collect();
        assert_eq!(rows, (0..MAX_LABEL_ROWS).collect::<Vec<_>>());
        assert!(
            labels
                .iter()
                .flatten()
                .all(|l| l.text.chars().count() <= LABEL_CHARS && l.text.ends_with('…'))
        );
        let doc = svg(&trace, "crowd");
        check_xml(&doc).expect("well-formed");
        assert_eq!(count(&doc, "<g class=\"event\">"), 12);
        assert!(doc.contains("8 event label(s) hidden"));
    }

    #[test]
    fn simultaneous_events_share_a_label() {
        let mut trace = demo(1, 10.0);
        trace.events = (1..=5)
            .map(|k| Event {
                t: 0.0,
                text: format!("T{k} online"),
            })
            .collect();
        trace.events.push(Event {
            t: 0.5,
            text: "armed".to_string(),
        });
        let doc = svg(&trace, "together");
        check_xml(&doc).expect("well-formed");
        assert!(doc.contains(">T1 online (+4)</text>"));
        assert!(
            doc.contains(
                "<title>0 s: T1 online\n0 s: T2 online\n0 s: T3 online\n0 s: T4 online\n0 s: T5 online</title>"
            )
        );
        assert!(doc.contains(">armed</text>"));
        assert!(!doc.contains("hidden"));
        assert_eq!(count(&doc, "<g class=\"event\">"), 6);
    }

    #[test]
    fn output_is_deterministic() {
        let trace = demo(6, 20.0);
        let a = svg(&trace, "same");
        let b = svg(&trace.clone(), "same");
        assert_eq!(a, b);
    }

    #[test]
    fn checker_rejects_broken_documents() {
        assert!(check_xml("<svg><g></svg>").is_err());
        assert!(check_xml("<svg>a & b</svg>").is_err());
        assert!(check_xml("<svg a=\"<\"/>").is_err());
        assert!(check_xml("<svg/><svg/>").is_err());
        assert!(check_xml("<svg x=\"1\" x=\"2\"/>").is_err());
        assert!(check_xml("<?xml version=\"1.0\"?>\n<svg><g a='1'>t &amp; &#233;</g></svg>\n").is_ok());
    }
}
