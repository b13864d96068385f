//! Trend charts drawn by the server as SVG: no script and no charting library in the
//! browser, and the same picture for a page, a report or a test.

use std::fmt::Write as _;

use crate::html::esc;

/// One line of a chart: (seconds from the chart's start, value or a gap).
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    /// Its name in the legend (`PV`).
    pub name: String,
    /// Its units (`kPa`).
    pub units: String,
    /// A CSS colour.
    pub color: &'static str,
    /// The points, in time order; `None` breaks the line.
    pub points: Vec<(f64, Option<f64>)>,
}

/// The chart's size in pixels.
pub const WIDTH: f64 = 900.0;
/// The chart's size in pixels.
pub const HEIGHT: f64 = 320.0;
const LEFT: f64 = 70.0;
const RIGHT: f64 = 70.0;
const TOP: f64 = 30.0;
const BOTTOM: f64 = 40.0;

/// A chart of `span` seconds: `left` on the left axis, `right` (if any) on the right
/// one. Whatever the values (none, one, all equal, not finite), it is a valid picture.
pub fn chart(title: &str, span: f64, left: &Series, right: Option<&Series>) -> String {
    let span = if span.is_finite() && span > 0.0 {
        span
    } else {
        1.0
    };
    let mut s = String::new();
    let _ = write!(
        s,
        r##"<svg xmlns="http://www.w3.org/2000/svg" viewBox="0 0 {WIDTH} {HEIGHT}" width="{WIDTH}" height="{HEIGHT}" font-family="sans-serif" font-size="12" role="img" aria-label="{}"><rect width="100%" height="100%" fill="#fff"/>"##,
        esc(title)
    );
    let _ = write!(
        s,
        r##"<text x="{LEFT}" y="18" font-size="14" font-weight="bold">{}</text>"##,
        esc(title)
    );
    let plot_w = WIDTH - LEFT - RIGHT;
    let plot_h = HEIGHT - TOP - BOTTOM;
    let _ = write!(
        s,
        r##"<rect x="{LEFT}" y="{TOP}" width="{plot_w}" height="{plot_h}" fill="none" stroke="#999"/>"##
    );
    // Time axis: minutes (or seconds) before the end.
    let (unit, per) = if span >= 7200.0 {
        ("h", 3600.0)
    } else if span >= 120.0 {
        ("min", 60.0)
    } else {
        ("s", 1.0)
    };
    for i in 0..=6 {
        let f = f64::from(i) / 6.0;
        let x = LEFT + f * plot_w;
        let ago = (1.0 - f) * span / per;
        let label = if i == 6 {
            "now".to_string()
        } else {
            format!("-{} {unit}", trim_number(ago))
        };
        let _ = write!(
            s,
            r##"<line x1="{x:.1}" y1="{TOP}" x2="{x:.1}" y2="{:.1}" stroke="#eee"/><text x="{x:.1}" y="{:.1}" text-anchor="middle" fill="#444">{label}</text>"##,
            TOP + plot_h,
            TOP + plot_h + 18.0
        );
    }
    let mut legend_x = LEFT + 260.0;
    for (series, side) in [(Some(left), Side::Left), (right, Side::Right)] {
        let Some(series) = series else { continue };
        let (lo, hi) = bounds(series);
        for i in 0..=4 {
            let f = f64::from(i) / 4.0;
            let y = TOP + plot_h - f * plot_h;
            let v = lo + f * (hi - lo);
            let (x, anchor) = match side {
                Side::Left => (LEFT - 6.0, "end"),
                Side::Right => (WIDTH - RIGHT + 6.0, "start"),
            };
            if side == Side::Left {
                let _ = write!(
                    s,
                    r##"<line x1="{LEFT}" y1="{y:.1}" x2="{:.1}" y2="{y:.1}" stroke="#eee"/>"##,
                    LEFT + plot_w
                );
            }
            let _ = write!(
                s,
                r##"<text x="{x:.1}" y="{:.1}" text-anchor="{anchor}" fill="{}">{}</text>"##,
                y + 4.0,
                series.color,
                esc(&format_value(v))
            );
        }
        let mut path = String::new();
        let mut pen_down = false;
        for &(t, v) in &series.points {
            let (Some(v), true) = (v.filter(|v| v.is_finite()), t.is_finite()) else {
                pen_down = false;
                continue;
            };
            let x = LEFT + (t / span).clamp(0.0, 1.0) * plot_w;
            let y = TOP + plot_h - ((v - lo) / (hi - lo)).clamp(0.0, 1.0) * plot_h;
            let _ = write!(path, "{}{x:.1},{y:.1} ", if pen_down { "L" } else { "M" });
            pen_down = true;
        }
        if !path.is_empty() {
            let _ = write!(
                s,
                r##"<path d="{}" fill="none" stroke="{}" stroke-width="1.8"/>"##,
                path.trim_end(),
                series.color
            );
        }
        let _ = write!(
            s,
            r##"<rect x="{legend_x:.1}" y="8" width="14" height="4" fill="{}"/><text x="{:.1}" y="14">{} ({})</text>"##,
            series.color,
            legend_x + 18.0,
            esc(&series.name),
            esc(&series.units)
        );
        legend_x += 200.0;
    }
    if left.points.iter().all(|(_, v)| v.is_none())
        && right.is_none_or(|r| r.points.iter().all(|(_, v)| v.is_none()))
    {
        let _ = write!(
            s,
            r##"<text x="{:.1}" y="{:.1}" text-anchor="middle" fill="#888">no values in this window</text>"##,
            LEFT + plot_w / 2.0,
            TOP + plot_h / 2.0
        );
    }
    s.push_str("</svg>");
    s
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Side {
    Left,
    Right,
}

/// The axis range of a series: its values with a margin; a flat or empty series
/// gets a range around its value.
fn bounds(series: &Series) -> (f64, f64) {
    let values = series
        .points
        .iter()
        .filter_map(|(_, v)| *v)
        .filter(|v| v.is_finite());
    let (mut lo, mut hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
        (lo.min(v), hi.max(v))
    });
    if !lo.is_finite() || !hi.is_finite() {
        return (0.0, 1.0);
    }
    // Values beyond this are drawn at the edge: the range itself stays finite.
    lo = lo.max(-1e300);
    hi = hi.min(1e300);
    let margin = (hi - lo) * 0.05;
    if !(margin.is_finite() && margin > f64::EPSILON * lo.abs().max(1.0)) {
        let pad = (lo.abs() * 0.01).max(0.5);
        return (lo - pad, hi + pad);
    }
    lo -= margin;
    hi += margin;
    (lo, hi)
}

/// A value with about four significant digits.
fn format_value(v: f64) -> String {
    let a = v.abs();
    if a != 0.0 && !(1e-3..1e6).contains(&a) {
        format!("{v:.3e}")
    } else if a >= 1000.0 {
        format!("{v:.0}")
    } else if a >= 10.0 {
        format!("{v:.2}")
    } else {
        format!("{v:.3}")
    }
}

fn trim_number(v: f64) -> String {
    let s = format!("{v:.1}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn series(points: Vec<(f64, Option<f64>)>) -> Series {
        Series {
            name: "PV <1>".into(),
            units: "kPa".into(),
            color: "#1f77b4",
            points,
        }
    }

    #[test]
    fn a_chart_with_a_gap_has_two_strokes() {
        let svg = chart(
            "PT-101",
            60.0,
            &series(vec![
                (0.0, Some(1.0)),
                (10.0, Some(2.0)),
                (20.0, None),
                (30.0, Some(3.0)),
            ]),
            None,
        );
        assert!(svg.starts_with("<svg") && svg.ends_with("</svg>"));
        let path = svg.split("<path d=\"").nth(1).unwrap();
        assert_eq!(path.split('"').next().unwrap().matches('M').count(), 2);
        assert!(svg.contains("PV &lt;1&gt;"), "names are escaped");
    }

    #[test]
    fn an_empty_chart_says_so() {
        let svg = chart("x", 0.0, &series(vec![]), Some(&series(vec![(1.0, None)])));
        assert!(svg.contains("no values in this window"));
    }

    proptest! {
        #[test]
        fn any_values_make_a_whole_picture(
            span in proptest::num::f64::ANY,
            points in proptest::collection::vec(
                (proptest::num::f64::ANY, proptest::option::of(proptest::num::f64::ANY)), 0..50),
        ) {
            let svg = chart("t", span, &series(points.clone()), Some(&series(points)));
            prop_assert!(svg.starts_with("<svg") && svg.ends_with("</svg>"));
            prop_assert!(!svg.contains("NaN") && !svg.contains("inf"));
        }
    }
}
