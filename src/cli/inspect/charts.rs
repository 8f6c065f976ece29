//! `inspect --histograms --charts DIR`: each histogram as a PNG bar chart
//! (plotters, drawn into a buffer with an embedded font, so it needs no
//! system fonts; written through `image` like every other picture).

use std::path::Path;

use anyhow::Result;
use plotters::prelude::*;

use crate::cli::exit::IoFailure;

/// DejaVu Sans Mono (its licence: `assets/fonts/DejaVu-LICENSE.txt`).
static FONT: &[u8] = include_bytes!("../../../assets/fonts/DejaVuSansMono.ttf");

/// Chart size in pixels.
const SIZE: (u32, u32) = (800, 480);

/// One bar chart: `labels[i]` under a bar of height `counts[i]`.
pub struct Chart<'a> {
    /// File stem (the histogram's JSON key).
    pub key: &'a str,
    /// Caption.
    pub title: &'a str,
    /// What the bars count (y axis).
    pub counts_what: &'a str,
    /// What the bins measure (x axis).
    pub bins_what: &'a str,
    /// Bin labels (x axis): each bin's lower bound.
    pub labels: Vec<String>,
    /// Bar heights.
    pub counts: Vec<u64>,
}

/// Writes `DIR/KEY.png` for every chart; returns the paths written.
pub fn write_charts(dir: &Path, charts: &[Chart<'_>]) -> Result<Vec<std::path::PathBuf>> {
    // The folder, made if missing: removed again when nothing could be
    // written into it (a full disk), kept once a chart is in it.
    let folder = illumnet::scratch::OutputDir::make(&dir.join("chart.png"))
        .map_err(|e| IoFailure(format!("cannot create {}: {e}", dir.display())))?;
    // Registering twice is harmless; a bad font would be a build defect.
    let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT);
    let mut written = Vec::new();
    for c in charts {
        let (w, h) = SIZE;
        let mut buf = vec![0u8; (w * h * 3) as usize];
        draw(c, &mut buf).map_err(|e| anyhow::anyhow!("drawing chart {}: {e}", c.key))?;
        let image = image::RgbImage::from_raw(w, h, buf).expect("buffer of the chart's size");
        let path = dir.join(format!("{}.png", c.key));
        save_png(&image, &path).map_err(|e| IoFailure(format!("cannot write {}: {e}", path.display())))?;
        written.push(path);
    }
    folder.keep();
    Ok(written)
}

/// Writes `image` as a PNG at `path` through a temporary file renamed into
/// place when complete (`scratch`), so that a full disk leaves no
/// truncated chart under its final name.
fn save_png(image: &image::RgbImage, path: &Path) -> std::io::Result<()> {
    illumnet::scratch::write_atomic(path, |w| {
        image.write_to(w, image::ImageFormat::Png).map_err(|e| match e {
            image::ImageError::IoError(e) => e,
            e => std::io::Error::other(e),
        })
    })
}

fn draw(c: &Chart<'_>, buf: &mut [u8]) -> Result<(), Box<dyn std::error::Error>> {
    let root = BitMapBackend::with_buffer(buf, SIZE).into_drawing_area();
    root.fill(&WHITE)?;
    let n = c.counts.len().max(1) as u32;
    let top = c.counts.iter().copied().max().unwrap_or(0).max(1);
    let mut chart = ChartBuilder::on(&root)
        .caption(c.title, ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(50)
        .y_label_area_size(80)
        .build_cartesian_2d((0..n).into_segmented(), 0..top + top / 20 + 1)?;
    let labels = &c.labels;
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_labels(labels.len())
        .x_label_formatter(&|v| match v {
            SegmentValue::CenterOf(i) => labels.get(*i as usize).cloned().unwrap_or_default(),
            _ => String::new(),
        })
        .x_desc(format!("{}: bins by their lower bound", c.bins_what))
        .y_desc(c.counts_what)
        .label_style(("sans-serif", 12))
        .draw()?;
    let colour = RGBColor(68, 1, 84).mix(0.85);
    chart.draw_series(c.counts.iter().enumerate().map(|(i, &k)| {
        let i = i as u32;
        let mut bar = Rectangle::new([(SegmentValue::Exact(i), 0), (SegmentValue::Exact(i + 1), k)], colour.filled());
        bar.set_margin(0, 0, 2, 2);
        bar
    }))?;
    root.present()?;
    Ok(())
}
