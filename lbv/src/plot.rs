//! Drawing a run's trace with plotters, as SVG or PNG: every thruster's speed (measured, and ordered dashed),
//! motor current and winding temperature (with the overtemperature levels), the battery voltage with the armed
//! periods shaded, a status strip (per thruster one lane per fault bit, grey where the master sees it offline),
//! and the run's events as numbered markers across all panels, listed under the plot.
//!
//! Text is drawn with DejaVu Sans built into the binary, so a PNG needs no fonts on the machine. The limits come
//! from the protocol and the firmware: full scale from tmc-proto's `Speed`, the overtemperature levels from
//! thruster-fw's `Thresholds::SPEC`, the fault bits and their names from tmc-proto's `Faults`. Long series are
//! cut down to at most [`MAX_POINTS`] points by keeping each bucket's minimum and maximum, so a one-sample spike
//! survives; values that are NaN or infinite are skipped.

use std::path::{Path, PathBuf};
use std::sync::Once;

use ab_glyph::{Font, FontRef, ScaleFont, point};
use plotters::coord::Shift;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use plotters_backend::{BackendColor, BackendCoord, DrawingErrorKind};
use thruster_fw::faults::Thresholds;
use tmc_proto::{Faults, Speed};

use crate::trace::{Event, Sample, Trace};

/// Most points drawn for one series; longer series are decimated by min/max per bucket.
pub const MAX_POINTS: usize = 2000;
/// Events listed under the plot (all are marked).
const MAX_LISTED: usize = 40;

/// The picture's file format.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// Scalable vector graphics.
    Svg,
    /// A bitmap.
    Png,
}

const WIDTH: u32 = 1600;
const LEFT: u32 = 96;
const RIGHT: u32 = 120;
const HEADER_H: u32 = 112;
const BAND_H: u32 = 44;
const RPM_H: u32 = 300;
const VALUE_H: u32 = 180;
const BATTERY_H: u32 = 120;
const LANE_H: u32 = 7;
const AXIS_H: u32 = 56;
const LINE_H: u32 = 21;
/// Events closer than this on the time axis share a marker label, px.
const GROUP_PX: i32 = 18;

const FONT: &str = "sans-serif";
const INK: RGBColor = RGBColor(0x22, 0x22, 0x22);
const MUTED: RGBColor = RGBColor(0x55, 0x55, 0x55);
const GRID: RGBColor = RGBColor(0xe6, 0xe6, 0xe6);
const OFFLINE: RGBColor = RGBColor(0x9a, 0x9a, 0x9a);
const ARMED: RGBColor = RGBColor(0xc3, 0xe6, 0xcb);
const EVENT: RGBColor = RGBColor(0x34, 0x3a, 0x40);
const OVERTEMP_SET: RGBColor = RGBColor(0xd9, 0x48, 0x0f);
const OVERTEMP_CLEAR: RGBColor = RGBColor(0xe6, 0x77, 0x00);
/// One colour per thruster (cycled beyond ten).
const PALETTE: [RGBColor; 10] = [
    RGBColor(0x1f, 0x77, 0xb4),
    RGBColor(0xff, 0x7f, 0x0e),
    RGBColor(0x2c, 0xa0, 0x2c),
    RGBColor(0xd6, 0x27, 0x28),
    RGBColor(0x94, 0x67, 0xbd),
    RGBColor(0x8c, 0x56, 0x4b),
    RGBColor(0xe3, 0x77, 0xc2),
    RGBColor(0x7f, 0x7f, 0x7f),
    RGBColor(0xbc, 0xbd, 0x22),
    RGBColor(0x17, 0xbe, 0xcf),
];
/// One colour per fault bit, lowest bit first.
const FAULT_COLOURS: [RGBColor; 5] = [
    RGBColor(0xe8, 0x59, 0x0c),
    RGBColor(0xc2, 0x25, 0x5c),
    RGBColor(0xf2, 0xb7, 0x05),
    RGBColor(0x5f, 0x3d, 0xc4),
    RGBColor(0x1c, 0x7e, 0xd6),
];

/// `--plot`: a file name ending in .svg or .png (the picture's format).
pub fn file(text: &str) -> Result<(PathBuf, Format), String> {
    let path = PathBuf::from(text);
    let extension = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
    match extension.as_deref() {
        Some("svg") => Ok((path, Format::Svg)),
        Some("png") => Ok((path, Format::Png)),
        _ => Err(format!("{text} does not end in .svg or .png")),
    }
}

/// Draw `trace` into the file at `path`.
pub fn write(trace: &Trace, title: &str, path: &Path, format: Format) -> Result<(), String> {
    let plot = Plot::new(trace);
    let size = plot.size();
    match format {
        Format::Svg => plot.draw(&SVGBackend::new(path, size).into_drawing_area(), title),
        Format::Png => plot.draw(
            &Lettered::new(BitMapBackend::new(path, size))?.into_drawing_area(),
            title,
        ),
    }
}

/// A bitmap backend that draws its own text: plotters' glyph drawing leaves out each glyph's side bearing, which
/// makes words ragged; this one places every glyph by its outline's bounds on a common baseline, with kerning.
struct Lettered<'a> {
    bitmap: BitMapBackend<'a>,
    regular: FontRef<'static>,
    bold: FontRef<'static>,
}

impl<'a> Lettered<'a> {
    fn new(bitmap: BitMapBackend<'a>) -> Result<Self, String> {
        let font = |bytes| FontRef::try_from_slice(bytes).map_err(error);
        Ok(Self {
            bitmap,
            regular: font(dejavu::sans::regular())?,
            bold: font(dejavu::sans::bold())?,
        })
    }

    /// The glyphs of `text` in `style`, placed on a baseline at the ascent, and the box they fill.
    fn layout<S: plotters_backend::BackendTextStyle>(
        &self,
        text: &str,
        style: &S,
    ) -> (Vec<ab_glyph::Glyph>, f32, f32, &FontRef<'static>) {
        let font = match style.style() {
            FontStyle::Bold => &self.bold,
            _ => &self.regular,
        };
        let scaled = font.as_scaled(style.size() as f32);
        let mut caret = 0.0;
        let mut previous = None;
        let glyphs = text
            .chars()
            .map(|c| {
                let id = scaled.glyph_id(c);
                if let Some(previous) = previous {
                    caret += scaled.kern(previous, id);
                }
                previous = Some(id);
                let glyph = id.with_scale_and_position(scaled.scale(), point(caret, scaled.ascent()));
                caret += scaled.h_advance(id);
                glyph
            })
            .collect();
        (glyphs, caret, scaled.height(), font)
    }
}

impl DrawingBackend for Lettered<'_> {
    type ErrorType = <BitMapBackend<'static> as DrawingBackend>::ErrorType;

    fn get_size(&self) -> (u32, u32) {
        self.bitmap.get_size()
    }

    fn ensure_prepared(&mut self) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.bitmap.ensure_prepared()
    }

    fn present(&mut self) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.bitmap.present()
    }

    fn draw_pixel(&mut self, at: BackendCoord, colour: BackendColor) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.bitmap.draw_pixel(at, colour)
    }

    fn draw_line<S: plotters_backend::BackendStyle>(
        &mut self,
        from: BackendCoord,
        to: BackendCoord,
        style: &S,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.bitmap.draw_line(from, to, style)
    }

    fn draw_rect<S: plotters_backend::BackendStyle>(
        &mut self,
        upper_left: BackendCoord,
        bottom_right: BackendCoord,
        style: &S,
        fill: bool,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.bitmap.draw_rect(upper_left, bottom_right, style, fill)
    }

    fn draw_path<S: plotters_backend::BackendStyle, I: IntoIterator<Item = BackendCoord>>(
        &mut self,
        path: I,
        style: &S,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.bitmap.draw_path(path, style)
    }

    fn draw_circle<S: plotters_backend::BackendStyle>(
        &mut self,
        center: BackendCoord,
        radius: u32,
        style: &S,
        fill: bool,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.bitmap.draw_circle(center, radius, style, fill)
    }

    fn fill_polygon<S: plotters_backend::BackendStyle, I: IntoIterator<Item = BackendCoord>>(
        &mut self,
        vertices: I,
        style: &S,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.bitmap.fill_polygon(vertices, style)
    }

    fn estimate_text_size<S: plotters_backend::BackendTextStyle>(
        &self,
        text: &str,
        style: &S,
    ) -> Result<(u32, u32), DrawingErrorKind<Self::ErrorType>> {
        let (_, width, height, _) = self.layout(text, style);
        Ok((width.ceil() as u32, height.ceil() as u32))
    }

    fn draw_text<S: plotters_backend::BackendTextStyle>(
        &mut self,
        text: &str,
        style: &S,
        at: BackendCoord,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        let colour = style.color();
        let (glyphs, width, height, font) = self.layout(text, style);
        let anchor = style.anchor();
        let dx = match anchor.h_pos {
            HPos::Left => 0.0,
            HPos::Center => -width / 2.0,
            HPos::Right => -width,
        };
        let dy = match anchor.v_pos {
            VPos::Top => 0.0,
            VPos::Center => -height / 2.0,
            VPos::Bottom => -height,
        };
        let transform = style.transform();
        let mut coverage = Vec::new();
        for glyph in glyphs {
            let Some(outline) = font.outline_glyph(glyph) else {
                continue;
            };
            let bounds = outline.px_bounds();
            outline.draw(|x, y, c| {
                let x = (bounds.min.x + dx).round() as i32 + x as i32;
                let y = (bounds.min.y + dy).round() as i32 + y as i32;
                coverage.push((transform.transform(x, y), c));
            });
        }
        let (w, h) = self.get_size();
        for ((x, y), c) in coverage {
            let (x, y) = (at.0 + x, at.1 + y);
            if c > 0.0 && (0..w as i32).contains(&x) && (0..h as i32).contains(&y) {
                let shade = BackendColor {
                    alpha: colour.alpha * f64::from(c.min(1.0)),
                    rgb: colour.rgb,
                };
                self.bitmap.draw_pixel((x, y), shade)?;
            }
        }
        Ok(())
    }
}

/// The fonts plotters draws text with: DejaVu Sans, from the binary.
fn register_fonts() {
    static FONTS: Once = Once::new();
    FONTS.call_once(|| {
        // DejaVu's files are valid fonts: registering them cannot fail; were it to, text would be missing and
        // drawing would say so.
        let _ = plotters::style::register_font(FONT, FontStyle::Normal, dejavu::sans::regular());
        let _ = plotters::style::register_font(FONT, FontStyle::Bold, dejavu::sans::bold());
    });
}

/// A drawing error in words.
fn error(error: impl std::fmt::Display) -> String {
    error.to_string()
}

fn colour(k: usize) -> RGBColor {
    PALETTE[k % PALETTE.len()]
}

fn text(size: u32) -> TextStyle<'static> {
    (FONT, size).into_font().color(&INK)
}

fn bold(size: u32) -> TextStyle<'static> {
    (FONT, size, FontStyle::Bold).into_font().color(&INK)
}

type Chart<'a, DB> = ChartContext<'a, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// Everything needed to draw one trace.
#[derive(Debug)]
struct Plot<'a> {
    samples: Vec<&'a Sample>,
    events: Vec<&'a Event>,
    thrusters: usize,
    t0: f64,
    t1: f64,
    /// Non-finite values met (and skipped).
    skipped: usize,
}

impl<'a> Plot<'a> {
    fn new(trace: &'a Trace) -> Self {
        let samples: Vec<&Sample> = trace.samples.iter().filter(|s| s.t.is_finite()).collect();
        let mut events: Vec<&Event> = trace.events.iter().filter(|e| e.t.is_finite()).collect();
        events.sort_by(|a, b| a.t.total_cmp(&b.t));
        let thrusters = samples.iter().map(|s| s.thrusters.len()).max().unwrap_or(0);
        let times = samples.iter().map(|s| s.t).chain(events.iter().map(|e| e.t));
        let (mut t0, mut t1) = times.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), t| (lo.min(t), hi.max(t)));
        if !(t1 - t0 > 0.0 && (t1 - t0).is_finite()) {
            (t0, t1) = if t0.is_finite() {
                (t0 - 0.5, t0 + 0.5)
            } else {
                (0.0, 1.0)
            };
        }
        let values = samples.iter().flat_map(|s| {
            let thrusters = s
                .thrusters
                .iter()
                .flat_map(|th| [th.rpm, th.current_a, th.temperature_c]);
            thrusters.chain([s.battery_v])
        });
        let skipped = values.filter(|v| !v.is_finite()).count()
            + (trace.samples.len() - samples.len())
            + (trace.events.len() - events.len());
        Plot {
            samples,
            events,
            thrusters,
            t0,
            t1,
            skipped,
        }
    }

    /// Width and height of the picture.
    fn size(&self) -> (u32, u32) {
        let listed = self.events.len().min(MAX_LISTED) as u32;
        (
            WIDTH,
            HEADER_H + BAND_H + self.panels_height() + (listed.div_ceil(2) + 3) * LINE_H,
        )
    }

    /// The panels' height, time axis included; none without samples.
    fn panels_height(&self) -> u32 {
        if self.samples.is_empty() {
            0
        } else {
            RPM_H + 2 * VALUE_H + BATTERY_H + self.strip_height() + AXIS_H
        }
    }

    fn strip_height(&self) -> u32 {
        self.thrusters as u32 * (Faults::ALL.iter().count() as u32 * LANE_H + 8)
    }

    /// The finite points (t, value) that `value` reads off the samples, decimated.
    fn series(&self, value: impl Fn(&Sample) -> Option<f64>) -> Vec<(f64, f64)> {
        let points: Vec<(f64, f64)> = self
            .samples
            .iter()
            .filter_map(|s| value(s).map(|v| (s.t, v)))
            .filter(|(_, v)| v.is_finite())
            .collect();
        decimate(&points, MAX_POINTS)
    }

    /// The time intervals where `on` holds, each sample lasting until the next one (the last as long as the one
    /// before it).
    fn runs(&self, on: impl Fn(&Sample) -> bool) -> Vec<(f64, f64)> {
        let mut runs = Vec::new();
        let mut open: Option<f64> = None;
        let mut last_dt = 0.0;
        for (i, s) in self.samples.iter().enumerate() {
            let end = match self.samples.get(i + 1) {
                Some(next) => {
                    last_dt = (next.t - s.t).max(0.0);
                    next.t
                }
                None => s.t + last_dt,
            };
            match (on(s), open) {
                (true, None) => open = Some(s.t),
                (false, Some(start)) => {
                    runs.push((start, s.t));
                    open = None;
                }
                _ => {}
            }
            if i + 1 == self.samples.len()
                && let Some(start) = open
            {
                runs.push((start, end));
            }
        }
        runs
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>, title: &str) -> Result<(), String> {
        register_fonts();
        root.fill(&WHITE).map_err(error)?;
        let (header, body) = root.split_vertically(HEADER_H);
        self.header(&header, title)?;
        let (band, body) = body.split_vertically(BAND_H);
        if !self.samples.is_empty() {
            let panels = body.split_by_breakpoints(
                [0; 0],
                [
                    RPM_H,
                    RPM_H + VALUE_H,
                    RPM_H + 2 * VALUE_H,
                    RPM_H + 2 * VALUE_H + BATTERY_H,
                    self.panels_height(),
                ],
            );
            let [rpm, current, temperature, battery, strip, ..] = panels.as_slice() else {
                return Err("the plot's panels do not fit".into());
            };
            let markers = self.speed(rpm)?;
            self.markers(&band, &markers)?;
            self.current(current)?;
            self.temperature(temperature)?;
            self.battery(battery)?;
            self.strip(strip)?;
        } else {
            band.draw_text("no samples", &text(20).color(&MUTED), (LEFT as i32, 10))
                .map_err(error)?;
        }
        self.footer(root, HEADER_H + BAND_H + self.panels_height())?;
        root.present().map_err(error)
    }

    /// Title, summary, and the legends: thrusters, line styles, status colours.
    fn header<DB: DrawingBackend>(&self, area: &DrawingArea<DB, Shift>, title: &str) -> Result<(), String> {
        let right = (WIDTH - RIGHT) as i32;
        area.draw_text(title, &bold(24), (LEFT as i32, 14)).map_err(error)?;
        let plural = |n: usize, what: &str| format!("{n} {what}{}", if n == 1 { "" } else { "s" });
        let summary = format!(
            "{} · {} · {} · {:.1} s to {:.1} s",
            plural(self.thrusters, "thruster"),
            plural(self.samples.len(), "sample"),
            plural(self.events.len(), "event"),
            self.t0,
            self.t1
        );
        let anchor = Pos::new(HPos::Right, VPos::Top);
        area.draw_text(&summary, &text(15).color(&MUTED).pos(anchor), (right, 20))
            .map_err(error)?;

        // Thrusters and line styles.
        let (mut x, y) = (LEFT as i32, 62);
        for k in 0..self.thrusters {
            area.draw(&PathElement::new([(x, y), (x + 22, y)], colour(k).stroke_width(4)))
                .map_err(error)?;
            area.draw_text(&format!("T{}", k + 1), &bold(15), (x + 27, y - 9))
                .map_err(error)?;
            x += 64;
        }
        x += 16;
        area.draw(&PathElement::new([(x, y), (x + 26, y)], MUTED.stroke_width(2)))
            .map_err(error)?;
        area.draw_text("measured", &text(15), (x + 32, y - 9)).map_err(error)?;
        x += 112;
        for dash in 0..3 {
            let start = x + dash * 10;
            area.draw(&PathElement::new([(start, y), (start + 6, y)], MUTED.stroke_width(2)))
                .map_err(error)?;
        }
        let ordered = format!("ordered (step × {}/{} rpm)", Speed::FULL_SCALE_RPM, Speed::MAX_STEP);
        area.draw_text(&ordered, &text(15), (x + 32, y - 9)).map_err(error)?;

        // The status strip's colours, on a line of their own.
        let (mut x, y) = (LEFT as i32, 88);
        area.draw_text("status:", &bold(15), (x, y - 9)).map_err(error)?;
        x += 64;
        let swatch = |x: i32, fill: RGBColor, name: &str| -> Result<i32, String> {
            area.draw(&Rectangle::new([(x, y - 6), (x + 16, y + 6)], fill.filled()))
                .map_err(error)?;
            area.draw_text(name, &text(15), (x + 21, y - 9)).map_err(error)?;
            let (w, _) = area.estimate_text_size(name, &text(15)).map_err(error)?;
            Ok(x + 21 + w as i32 + 16)
        };
        for (fault, fill) in Faults::ALL.iter().zip(FAULT_COLOURS) {
            x = swatch(x, fill, fault.name())?;
        }
        x = swatch(x, OFFLINE, "offline")?;
        swatch(x, ARMED, "armed")?;
        Ok(())
    }

    /// A value panel sharing the time axis: frame, grid, y labels and its name.
    fn panel<'b, DB: DrawingBackend>(
        &self,
        area: &'b DrawingArea<DB, Shift>,
        name: &str,
        (lo, hi): (f64, f64),
    ) -> Result<Chart<'b, DB>, String> {
        let mut chart = ChartBuilder::on(area)
            .margin_top(6)
            .margin_bottom(6)
            .margin_right(RIGHT)
            .y_label_area_size(LEFT)
            .build_cartesian_2d(self.t0..self.t1, lo..hi)
            .map_err(error)?;
        chart
            .configure_mesh()
            .x_labels(12)
            .y_labels(6)
            .x_label_formatter(&|_| String::new())
            .y_label_formatter(&|v| tick(*v))
            .y_desc(name)
            .axis_desc_style(text(16))
            .label_style(text(14))
            .bold_line_style(GRID)
            .light_line_style(WHITE)
            .axis_style(OFFLINE)
            .draw()
            .map_err(error)?;
        self.event_lines(&mut chart, lo, hi)?;
        Ok(chart)
    }

    /// Thin vertical lines at the events.
    fn event_lines<DB: DrawingBackend>(&self, chart: &mut Chart<DB>, lo: f64, hi: f64) -> Result<(), String> {
        let style = EVENT.mix(0.45).stroke_width(1);
        for event in &self.events {
            chart
                .draw_series(LineSeries::new([(event.t, lo), (event.t, hi)], style))
                .map_err(error)?;
        }
        Ok(())
    }

    /// The speed panel; returns where the events' markers go along the top, in pixels.
    fn speed<DB: DrawingBackend>(&self, area: &DrawingArea<DB, Shift>) -> Result<Vec<i32>, String> {
        let per_step = f64::from(Speed::FULL_SCALE_RPM) / f64::from(Speed::MAX_STEP);
        let measured: Vec<_> = (0..self.thrusters)
            .map(|k| self.series(|s| s.thrusters.get(k).map(|th| th.rpm)))
            .collect();
        let ordered: Vec<_> = (0..self.thrusters)
            .map(|k| self.series(|s| s.thrusters.get(k).map(|th| f64::from(th.ordered_step) * per_step)))
            .collect();
        let range = span(measured.iter().chain(&ordered).flatten().map(|(_, v)| *v), &[0.0]);
        let mut chart = self.panel(area, "speed (rpm)", range)?;
        if range.0 < 0.0 && range.1 > 0.0 {
            let zero = LineSeries::new([(self.t0, 0.0), (self.t1, 0.0)], OFFLINE.stroke_width(1));
            chart.draw_series(zero).map_err(error)?;
        }
        for (k, points) in ordered.iter().enumerate() {
            let dashed = DashedLineSeries::new(points.iter().copied(), 7, 5, colour(k).mix(0.8).stroke_width(2));
            chart.draw_series(dashed).map_err(error)?;
        }
        for (k, points) in measured.iter().enumerate() {
            self.line(&mut chart, points, colour(k), 2)?;
        }
        Ok(self
            .events
            .iter()
            .map(|event| chart.backend_coord(&(event.t, range.1)).0)
            .collect())
    }

    /// A series as a line, or a dot when it is a single point (which a line would not show).
    fn line<DB: DrawingBackend>(
        &self,
        chart: &mut Chart<DB>,
        points: &[(f64, f64)],
        colour: RGBColor,
        width: u32,
    ) -> Result<(), String> {
        if let [point] = points {
            chart
                .draw_series([Circle::new(*point, 3, colour.filled())])
                .map_err(error)?;
        } else {
            chart
                .draw_series(LineSeries::new(points.iter().copied(), colour.stroke_width(width)))
                .map_err(error)?;
        }
        Ok(())
    }

    fn current<DB: DrawingBackend>(&self, area: &DrawingArea<DB, Shift>) -> Result<(), String> {
        let currents: Vec<_> = (0..self.thrusters)
            .map(|k| self.series(|s| s.thrusters.get(k).map(|th| th.current_a)))
            .collect();
        let range = span(currents.iter().flatten().map(|(_, v)| *v), &[0.0]);
        let mut chart = self.panel(area, "current (A)", range)?;
        for (k, points) in currents.iter().enumerate() {
            self.line(&mut chart, points, colour(k), 2)?;
        }
        Ok(())
    }

    fn temperature<DB: DrawingBackend>(&self, area: &DrawingArea<DB, Shift>) -> Result<(), String> {
        let set = f64::from(Thresholds::SPEC.overtemp_set_decicelsius) / 10.0;
        let clear = f64::from(Thresholds::SPEC.overtemp_clear_decicelsius) / 10.0;
        let temperatures: Vec<_> = (0..self.thrusters)
            .map(|k| self.series(|s| s.thrusters.get(k).map(|th| th.temperature_c)))
            .collect();
        let range = span(temperatures.iter().flatten().map(|(_, v)| *v), &[set, clear]);
        let mut chart = self.panel(area, "winding temp (°C)", range)?;
        for (level, name, colour, below) in [
            (set, "set", OVERTEMP_SET, false),
            (clear, "clear", OVERTEMP_CLEAR, true),
        ] {
            let dashed = DashedLineSeries::new([(self.t0, level), (self.t1, level)], 6, 4, colour.stroke_width(2));
            chart.draw_series(dashed).map_err(error)?;
            let (x, y) = chart.backend_coord(&(self.t1, level));
            let anchor = Pos::new(HPos::Left, if below { VPos::Top } else { VPos::Bottom });
            let label = format!("{level:.0} °C {name}");
            area.draw_text(
                &label,
                &text(14).color(&colour).pos(anchor),
                (x + 6, y - area.get_base_pixel().1),
            )
            .map_err(error)?;
        }
        for (k, points) in temperatures.iter().enumerate() {
            self.line(&mut chart, points, colour(k), 2)?;
        }
        Ok(())
    }

    /// The battery voltage, over green where the vehicle is armed.
    fn battery<DB: DrawingBackend>(&self, area: &DrawingArea<DB, Shift>) -> Result<(), String> {
        let volts = self.series(|s| Some(s.battery_v));
        let (lo, hi) = span(volts.iter().map(|(_, v)| *v), &[]);
        let (lo, hi) = if hi - lo < 0.2 { (lo - 0.1, hi + 0.1) } else { (lo, hi) };
        let mut chart = self.panel(area, "battery (V)", (lo, hi))?;
        let armed = self.runs(|s| s.armed);
        chart
            .draw_series(
                armed
                    .iter()
                    .map(|&(a, b)| Rectangle::new([(a, lo), (b, hi)], ARMED.filled())),
            )
            .map_err(error)?;
        self.line(&mut chart, &volts, INK, 2)
    }

    /// Per thruster a row of fault lanes, grey where offline; the time axis below.
    fn strip<DB: DrawingBackend>(&self, area: &DrawingArea<DB, Shift>) -> Result<(), String> {
        let lanes = Faults::ALL.iter().count();
        let rows = self.thrusters as f64;
        let mut chart = ChartBuilder::on(area)
            .margin_top(6)
            .margin_right(RIGHT)
            .y_label_area_size(LEFT)
            .x_label_area_size(AXIS_H - 6)
            .build_cartesian_2d(self.t0..self.t1, 0.0..rows)
            .map_err(error)?;
        chart
            .configure_mesh()
            .x_labels(12)
            .y_labels(0)
            .x_label_formatter(&|v| tick(*v))
            .x_desc("time (s)")
            .axis_desc_style(text(16))
            .label_style(text(14))
            .bold_line_style(GRID)
            .light_line_style(WHITE)
            .axis_style(OFFLINE)
            .draw()
            .map_err(error)?;
        // Row k from the top: y from rows - k (top) down to rows - k - 1.
        for k in 0..self.thrusters {
            let top = rows - k as f64;
            let offline = self.runs(|s| s.thrusters.get(k).is_some_and(|th| !th.online));
            chart
                .draw_series(
                    offline
                        .iter()
                        .map(|&(a, b)| Rectangle::new([(a, top), (b, top - 1.0)], OFFLINE.mix(0.55).filled())),
                )
                .map_err(error)?;
            for (j, (fault, fill)) in Faults::ALL.iter().zip(FAULT_COLOURS).enumerate() {
                let runs = self.runs(|s| s.thrusters.get(k).is_some_and(|th| th.faults & fault.bits() != 0));
                let (lane_top, lane_bottom) = (
                    top - (j as f64 + 0.5) / (lanes as f64 + 1.0),
                    top - (j as f64 + 1.4) / (lanes as f64 + 1.0),
                );
                chart
                    .draw_series(
                        runs.iter()
                            .map(|&(a, b)| Rectangle::new([(a, lane_top), (b, lane_bottom)], fill.filled())),
                    )
                    .map_err(error)?;
            }
            let (x, y) = chart.backend_coord(&(self.t0, top - 0.5));
            let anchor = Pos::new(HPos::Right, VPos::Center);
            let base = area.get_base_pixel();
            area.draw_text(
                &format!("T{}", k + 1),
                &bold(15).color(&colour(k)).pos(anchor),
                (x - 10 - base.0, y - base.1),
            )
            .map_err(error)?;
            chart
                .draw_series(LineSeries::new([(self.t0, top - 1.0), (self.t1, top - 1.0)], GRID))
                .map_err(error)?;
        }
        self.event_lines(&mut chart, 0.0, rows)
    }

    /// Numbers over the events' lines, in the band above the plot; events close together share one ("3-5").
    fn markers<DB: DrawingBackend>(&self, band: &DrawingArea<DB, Shift>, xs: &[i32]) -> Result<(), String> {
        let base = band.get_base_pixel();
        let mut taken = [i32::MIN; 2];
        let mut i = 0;
        while let Some(&x) = xs.get(i) {
            let group = xs
                .iter()
                .skip(i)
                .take_while(|&&other| other - x <= GROUP_PX)
                .count()
                .max(1);
            let label = if group == 1 {
                format!("{}", i + 1)
            } else {
                format!("{}-{}", i + 1, i + group)
            };
            let (w, _) = band.estimate_text_size(&label, &text(13)).map_err(error)?;
            let (left, right) = (x - w as i32 / 2 - 3, x + w as i32 / 2 + 3);
            if let Some(row) = taken.iter().position(|&end| left > end + 2) {
                let y = 4 + row as i32 * 19;
                band.draw(&Rectangle::new(
                    [(left - base.0, y), (right - base.0, y + 17)],
                    EVENT.mix(0.08).filled(),
                ))
                .map_err(error)?;
                let anchor = Pos::new(HPos::Center, VPos::Top);
                band.draw_text(&label, &text(13).color(&EVENT).pos(anchor), (x - base.0, y + 2))
                    .map_err(error)?;
                taken[row] = right;
            }
            i += group;
        }
        Ok(())
    }

    /// The notes, then the events listed by number in two columns.
    fn footer<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>, top: u32) -> Result<(), String> {
        let mut notes = Vec::new();
        if self.samples.len() > MAX_POINTS {
            notes.push(format!(
                "long series drawn as min/max per bucket (at most {MAX_POINTS} points each)"
            ));
        }
        if self.skipped > 0 {
            notes.push(format!("{} non-finite values skipped", self.skipped));
        }
        if self.events.len() > MAX_LISTED {
            notes.push(format!(
                "events: the first {MAX_LISTED} of {} listed",
                self.events.len()
            ));
        }
        let mut y = top as i32 + 8;
        if !notes.is_empty() {
            root.draw_text(&notes.join(" · "), &text(14).color(&MUTED), (LEFT as i32, y))
                .map_err(error)?;
        }
        y += LINE_H as i32;
        let column = (WIDTH - LEFT - RIGHT) as i32 / 2;
        let rows = self.events.len().min(MAX_LISTED).div_ceil(2);
        for (i, event) in self.events.iter().take(MAX_LISTED).enumerate() {
            let (col, row) = (i / rows.max(1), i % rows.max(1));
            let (x, y) = (LEFT as i32 + col as i32 * column, y + row as i32 * LINE_H as i32);
            root.draw_text(&format!("{}", i + 1), &bold(14), (x, y))
                .map_err(error)?;
            let line = format!("{:>8.2} s   {}", event.t, one_line(&event.text, 70));
            root.draw_text(&line, &text(14), (x + 34, y)).map_err(error)?;
        }
        Ok(())
    }
}

/// The range of `values` and `include`, padded by 5 % (a flat series gets a unit range).
fn span(values: impl Iterator<Item = f64>, include: &[f64]) -> (f64, f64) {
    let (lo, hi) = values
        .chain(include.iter().copied())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| (lo.min(v), hi.max(v)));
    if !(lo.is_finite() && hi.is_finite()) {
        return (0.0, 1.0);
    }
    let pad = ((hi - lo) * 0.05).max(0.5);
    (lo - pad, hi + pad)
}

/// A tick label: as few decimals as the value needs, up to two.
fn tick(v: f64) -> String {
    let text = format!("{v:.2}");
    let text = text.trim_end_matches('0').trim_end_matches('.');
    if text == "-0" { "0".into() } else { text.into() }
}

/// `text` on one line, at most `max` characters.
fn one_line(text: &str, max: usize) -> String {
    let flat: String = text.chars().map(|c| if c.is_control() { ' ' } else { c }).collect();
    if flat.chars().count() > max {
        flat.chars().take(max - 1).chain(['…']).collect()
    } else {
        flat
    }
}

/// At most about `max` points: each of `max / 2` buckets keeps its minimum and maximum, in time order.
fn decimate(points: &[(f64, f64)], max: usize) -> Vec<(f64, f64)> {
    if points.len() <= max {
        return points.to_vec();
    }
    let buckets = (max / 2).max(1);
    let per = points.len().div_ceil(buckets);
    let mut out = Vec::with_capacity(max);
    for bucket in points.chunks(per) {
        let low = bucket.iter().enumerate().min_by(|a, b| a.1.1.total_cmp(&b.1.1));
        let high = bucket.iter().enumerate().max_by(|a, b| a.1.1.total_cmp(&b.1.1));
        if let (Some((i, &low)), Some((j, &high))) = (low, high) {
            if i == j {
                out.push(low);
            } else if i < j {
                out.extend([low, high]);
            } else {
                out.extend([high, low]);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trace::ThrusterSample;

    /// Two thrusters over 20 s at 100 Hz: T1 runs and stalls, T2 drops offline; armed from 1 s; a few events.
    fn trace() -> Trace {
        let samples = (0..2000)
            .map(|i| {
                let t = f64::from(i) / 100.0;
                let stalled = (8.0..10.0).contains(&t);
                let thruster = |k: usize| ThrusterSample {
                    rpm: if stalled && k == 0 {
                        0.0
                    } else {
                        1500.0 * (t / 3.0).min(1.0)
                    },
                    current_a: if stalled && k == 0 { 8.0 } else { 0.5 },
                    temperature_c: 20.0 + t,
                    faults: if stalled && k == 0 { Faults::STALL.bits() } else { 0 },
                    online: !(k == 1 && (12.0..13.0).contains(&t)),
                    ordered_step: 34,
                };
                Sample {
                    t,
                    thrusters: vec![thruster(0), thruster(1)],
                    battery_v: 28.5 - if stalled { 0.3 } else { 0.0 },
                    armed: t >= 1.0,
                }
            })
            .collect();
        let events = [
            (1.0, "armed"),
            (8.0, "T1: propeller blocked"),
            (12.0, "T2 offline"),
            (f64::NAN, "lost"),
        ]
        .iter()
        .map(|&(t, text)| Event { t, text: text.into() })
        .collect();
        Trace { samples, events }
    }

    fn temp(name: &str) -> std::path::PathBuf {
        std::env::temp_dir().join(format!("lbv-plot-{}-{name}", std::process::id()))
    }

    #[test]
    fn svg_names_the_panels_the_limits_and_the_faults() {
        let path = temp("run.svg");
        write(&trace(), "a run", &path, Format::Svg).unwrap();
        let svg = std::fs::read_to_string(&path).unwrap();
        let _ = std::fs::remove_file(&path);
        assert!(svg.starts_with("<svg"), "{}", &svg[..80]);
        for text in [
            "a run",
            "speed (rpm)",
            "current (A)",
            "winding temp (°C)",
            "battery (V)",
            "time (s)",
            "110 °C set",
            "100 °C clear",
            "ordered (step × 4500/102 rpm)",
            "T1: propeller blocked",
            "1 non-finite values skipped",
        ] {
            assert!(svg.contains(text), "{text:?} missing");
        }
        for fault in Faults::ALL.iter() {
            assert!(svg.contains(fault.name()), "{}", fault.name());
        }
    }

    /// The PNG's text is drawn from the font in the binary: the title's band has ink, and each thruster's colour
    /// shows in the speed panel.
    #[test]
    fn png_draws_text_and_series() {
        let path = temp("run.png");
        write(&trace(), "a run", &path, Format::Png).unwrap();
        let image = image::open(&path).unwrap().to_rgb8();
        let _ = std::fs::remove_file(&path);
        assert_eq!(image.width(), WIDTH);
        let ink = |x0: u32, y0: u32, x1: u32, y1: u32, pick: &dyn Fn(&image::Rgb<u8>) -> bool| {
            (y0..y1)
                .flat_map(|y| (x0..x1).map(move |x| (x, y)))
                .filter(|&(x, y)| pick(image.get_pixel(x, y)))
                .count()
        };
        let dark = |p: &image::Rgb<u8>| p.0.iter().all(|&c| c < 100);
        assert!(ink(LEFT, 10, LEFT + 200, 44, &dark) > 200, "the title is drawn");
        let speed = (LEFT, HEADER_H + BAND_H, WIDTH - RIGHT, HEADER_H + BAND_H + RPM_H);
        for k in 0..2 {
            let RGBColor(r, g, b) = colour(k);
            let same = move |p: &image::Rgb<u8>| p.0 == [r, g, b];
            assert!(
                ink(speed.0, speed.1, speed.2, speed.3, &same) > 100,
                "thruster {k}'s line"
            );
        }
    }

    #[test]
    fn a_trace_without_samples_still_draws() {
        let path = temp("empty.svg");
        let trace = Trace {
            samples: Vec::new(),
            events: vec![Event {
                t: 0.5,
                text: "nothing ran".into(),
            }],
        };
        write(&trace, "empty", &path, Format::Svg).unwrap();
        let svg = std::fs::read_to_string(&path).unwrap();
        let _ = std::fs::remove_file(&path);
        assert!(svg.contains("no samples") && svg.contains("nothing ran"));
    }

    #[test]
    fn the_same_trace_gives_the_same_picture() {
        let (a, b) = (temp("a.svg"), temp("b.svg"));
        write(&trace(), "t", &a, Format::Svg).unwrap();
        write(&trace(), "t", &b, Format::Svg).unwrap();
        let same = std::fs::read(&a).unwrap() == std::fs::read(&b).unwrap();
        let _ = (std::fs::remove_file(&a), std::fs::remove_file(&b));
        assert!(same);
    }

    #[test]
    fn decimation_keeps_a_one_sample_spike_and_the_order() {
        let mut points: Vec<(f64, f64)> = (0..100_000).map(|i| (f64::from(i), 0.0)).collect();
        points[54_321].1 = 9.0;
        let kept = decimate(&points, MAX_POINTS);
        assert!(kept.len() <= MAX_POINTS);
        assert!(kept.contains(&(54_321.0, 9.0)));
        assert!(kept.windows(2).all(|w| w[0].0 < w[1].0));
        assert_eq!(decimate(&points[..10], MAX_POINTS), &points[..10]);
    }

    #[test]
    fn runs_last_until_the_next_sample() {
        let trace = trace();
        let plot = Plot::new(&trace);
        let stalls = plot.runs(|s| s.thrusters[0].faults != 0);
        assert_eq!(stalls.len(), 1);
        let (a, b) = stalls[0];
        assert!((a - 8.0).abs() < 1e-9 && (b - 10.0).abs() < 1e-9, "{a} {b}");
        let armed = plot.runs(|s| s.armed);
        assert!(
            (armed[0].1 - 20.0).abs() < 1e-9,
            "the last sample lasts one period: {armed:?}"
        );
    }
}
