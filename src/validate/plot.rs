//! SVG plots of a signal: both waveforms overlaid, and the error below.

use plotters::prelude::*;

/// Render `reference` and `test` (same time axis) and their difference.
pub fn svg(name: &str, time: &[f64], reference: &[f64], test: &[f64]) -> Result<String, String> {
    let mut out = String::new();
    {
        let root = SVGBackend::with_string(&mut out, (900, 600)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| e.to_string())?;
        let (upper, lower) = root.split_vertically(400);
        let (t0, t1) = (
            time.first().copied().unwrap_or(0.0),
            time.last().copied().unwrap_or(1.0).max(1e-300),
        );
        let finite = |v: &[f64]| -> (f64, f64) {
            let (lo, hi) = v
                .iter()
                .filter(|x| x.is_finite())
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
                    (a.min(x), b.max(x))
                });
            if lo.is_finite() && hi > lo {
                let pad = 0.05 * (hi - lo);
                (lo - pad, hi + pad)
            } else if lo.is_finite() {
                (lo - 1.0, lo + 1.0)
            } else {
                (-1.0, 1.0)
            }
        };
        let both: Vec<f64> = reference.iter().chain(test).copied().collect();
        let (lo, hi) = finite(&both);
        let mut chart = ChartBuilder::on(&upper)
            .caption(
                format!("{name}: ngspice (reference) and kausal"),
                ("sans-serif", 18),
            )
            .margin(10)
            .x_label_area_size(30)
            .y_label_area_size(70)
            .build_cartesian_2d(t0..t1, lo..hi)
            .map_err(|e| e.to_string())?;
        chart
            .configure_mesh()
            .x_desc("time (s)")
            .draw()
            .map_err(|e| e.to_string())?;
        chart
            .draw_series(LineSeries::new(
                time.iter().copied().zip(reference.iter().copied()),
                BLUE.stroke_width(2),
            ))
            .map_err(|e| e.to_string())?
            .label("ngspice")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLUE));
        chart
            .draw_series(LineSeries::new(
                time.iter().copied().zip(test.iter().copied()),
                RED,
            ))
            .map_err(|e| e.to_string())?
            .label("kausal")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RED));
        chart
            .configure_series_labels()
            .border_style(BLACK)
            .draw()
            .map_err(|e| e.to_string())?;
        let err: Vec<f64> = test.iter().zip(reference).map(|(a, b)| a - b).collect();
        let (elo, ehi) = finite(&err);
        let mut echart = ChartBuilder::on(&lower)
            .caption("kausal - ngspice", ("sans-serif", 14))
            .margin(10)
            .x_label_area_size(30)
            .y_label_area_size(70)
            .build_cartesian_2d(t0..t1, elo..ehi)
            .map_err(|e| e.to_string())?;
        echart.configure_mesh().draw().map_err(|e| e.to_string())?;
        echart
            .draw_series(LineSeries::new(
                time.iter().copied().zip(err.iter().copied()),
                BLACK,
            ))
            .map_err(|e| e.to_string())?;
        root.present().map_err(|e| e.to_string())?;
    }
    Ok(out)
}
