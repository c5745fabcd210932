//! The work-precision plot: error against time, log-log, a line per solver.

use plotters::prelude::*;

use super::CircuitBench;

const COLOURS: [RGBColor; 7] = [
    RGBColor(0, 90, 200),
    RGBColor(0, 150, 80),
    RGBColor(120, 60, 170),
    RGBColor(230, 120, 0),
    RGBColor(200, 30, 30),
    RGBColor(90, 90, 90),
    RGBColor(0, 160, 170),
];

/// An SVG of `b`'s measurements: error on x, solve time on y (both log).
pub fn work_precision_svg(b: &CircuitBench) -> Result<String, String> {
    let pts: Vec<_> = b
        .points
        .iter()
        .filter(|p| p.failed.is_none() && p.solve_seconds > 0.0)
        .collect();
    let floor = 1e-14;
    let (mut x0, mut x1, mut y0, mut y1) = (f64::INFINITY, 0.0f64, f64::INFINITY, 0.0f64);
    for p in &pts {
        let e = p.error.max(floor);
        x0 = x0.min(e);
        x1 = x1.max(e);
        y0 = y0.min(p.solve_seconds);
        y1 = y1.max(p.solve_seconds);
    }
    if pts.is_empty() {
        (x0, x1, y0, y1) = (1e-9, 1.0, 1e-4, 1.0);
    }
    let mut out = String::new();
    {
        let root = SVGBackend::with_string(&mut out, (800, 560)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| e.to_string())?;
        let mut chart = ChartBuilder::on(&root)
            .caption(
                format!("{}: work-precision", super::stem(&b.netlist)),
                ("sans-serif", 18),
            )
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(70)
            .build_cartesian_2d(
                ((x0 / 3.0)..(x1 * 3.0)).log_scale(),
                ((y0 / 2.0)..(y1 * 2.0)).log_scale(),
            )
            .map_err(|e| e.to_string())?;
        chart
            .configure_mesh()
            .x_desc("max error")
            .y_desc("solve time (s)")
            .x_label_formatter(&|x| format!("{x:.0e}"))
            .y_label_formatter(&|y| format!("{y:.0e}"))
            .draw()
            .map_err(|e| e.to_string())?;
        let mut solvers: Vec<&str> = pts.iter().map(|p| p.solver.as_str()).collect();
        solvers.dedup();
        for (k, s) in solvers.iter().enumerate() {
            let colour = COLOURS[k % COLOURS.len()];
            let line: Vec<(f64, f64)> = pts
                .iter()
                .filter(|p| p.solver == *s)
                .map(|p| (p.error.max(floor), p.solve_seconds))
                .collect();
            chart
                .draw_series(LineSeries::new(line.clone(), colour.stroke_width(2)))
                .map_err(|e| e.to_string())?
                .label(*s)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour));
            chart
                .draw_series(line.into_iter().map(|p| Circle::new(p, 3, colour.filled())))
                .map_err(|e| e.to_string())?;
        }
        chart
            .configure_series_labels()
            .border_style(BLACK)
            .background_style(WHITE.mix(0.8))
            .draw()
            .map_err(|e| e.to_string())?;
        root.present().map_err(|e| e.to_string())?;
    }
    Ok(out)
}
