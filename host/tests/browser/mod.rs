//! The HTML reports checked in a real browser: Debian's headless Chromium (installed by
//! `scripts/setup`) renders the page and each of its figures; a figure is rendered when its
//! box in the screenshot is not blank, and the page must log nothing to the console.
//! Skips with a message when Chromium is absent, except in CI (`CI` or
//! `DYNACAL_REQUIRE_BROWSER` set), where that fails.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;

/// The flags every run uses: headless, no sandbox (CI runs as root), no GPU, and nothing
/// that reaches for the network (this machine's network is closed).
const FLAGS: [&str; 8] = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
];

/// Width of each figure's box in the page of figures, CSS pixels.
const CELL_W: u32 = 800;

/// Chromium's path: `$CHROMIUM`, else `/usr/bin/chromium`; None after saying so when absent
/// outside CI.
pub fn chromium_or_skip() -> Option<PathBuf> {
    let path = std::env::var_os("CHROMIUM")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("/usr/bin/chromium"));
    if path.exists() {
        return Some(path);
    }
    let required =
        std::env::var_os("CI").is_some() || std::env::var_os("DYNACAL_REQUIRE_BROWSER").is_some();
    assert!(
        !required,
        "{} is missing: run scripts/setup",
        path.display()
    );
    eprintln!(
        "SKIPPED: {} not found (scripts/setup installs it)",
        path.display()
    );
    None
}

fn run(chromium: &Path, profile: &Path, args: &[String]) -> std::process::Output {
    let out = Command::new("timeout")
        .arg("120")
        .arg(chromium)
        .args(FLAGS)
        .arg(format!("--user-data-dir={}", profile.display()))
        .args(args)
        .output()
        .expect("run chromium");
    assert!(
        out.status.success(),
        "chromium failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// RGB pixels of a PNG and its width.
fn pixels(png_path: &Path) -> (Vec<[u8; 3]>, u32) {
    let decoder = png::Decoder::new(std::io::BufReader::new(
        std::fs::File::open(png_path).expect("open the screenshot"),
    ));
    let mut reader = decoder.read_info().expect("a PNG");
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).expect("a frame");
    let channels = info.color_type.samples();
    let rgb = buf[..info.buffer_size()]
        .chunks(channels)
        .map(|p| [p[0], p[1], p[2]])
        .collect();
    (rgb, info.width)
}

fn inked(p: &[u8; 3]) -> bool {
    p.iter().any(|&c| c < 200)
}

/// What the browser made of a report.
#[derive(Debug)]
pub struct Rendered {
    /// Figures in the page.
    pub figures: usize,
    /// Share of each figure's box that is drawn (not near-white).
    pub figure_ink: Vec<f64>,
    /// Share of the page's first screen that is drawn.
    pub page_ink: f64,
    /// What the page logged to the console.
    pub console: Vec<String>,
}

/// A numeric attribute of an SVG element's opening tag (plotters writes `width="1100"`).
fn attribute(svg: &str, name: &str) -> f64 {
    let tag = &svg[..svg.find('>').unwrap()];
    let key = format!(" {name}=\"");
    let start = tag
        .find(&key)
        .unwrap_or_else(|| panic!("no {name} in {tag}"))
        + key.len();
    let len = tag[start..].find('"').unwrap();
    tag[start..start + len].parse().unwrap()
}

/// The SVG elements of the report's figures, in order.
fn figure_svgs(html: &str) -> Vec<&str> {
    let mut out = Vec::new();
    let mut rest = html;
    while let Some(start) = rest.find("<svg class=\"figure\"") {
        let tail = &rest[start..];
        let end = tail.find("</svg>").expect("a closed svg") + "</svg>".len();
        out.push(&tail[..end]);
        rest = &tail[end..];
    }
    out
}

/// Renders `report` (a report.html) in Chromium: the page, its console, and each figure in
/// a box of its own.
pub fn render(chromium: &Path, report: &Path) -> Rendered {
    let dir = tempfile::tempdir().unwrap();
    let profile = dir.path().join("profile");
    let url = format!("file://{}", report.canonicalize().unwrap().display());
    let page_png = dir.path().join("page.png");
    let out = run(
        chromium,
        &profile,
        &[
            "--enable-logging=stderr".into(),
            "--v=0".into(),
            "--window-size=1280,2000".into(),
            format!("--screenshot={}", page_png.display()),
            url,
        ],
    );
    let console = String::from_utf8_lossy(&out.stderr)
        .lines()
        .filter(|l| l.contains(":CONSOLE"))
        .map(str::to_string)
        .collect();
    let (page, _) = pixels(&page_png);
    let page_ink = page.iter().filter(|p| inked(p)).count() as f64 / page.len() as f64;

    let html = std::fs::read_to_string(report).unwrap();
    let svgs = figure_svgs(&html);
    // One column, each figure in a box of its own aspect ratio, CELL_W wide.
    let boxes: Vec<(u32, u32)> = {
        let mut top = 0;
        svgs.iter()
            .map(|svg| {
                let (w, h) = (attribute(svg, "width"), attribute(svg, "height"));
                let height = (f64::from(CELL_W) * h / w).round() as u32;
                let b = (top, height);
                top += height;
                b
            })
            .collect()
    };
    let total = boxes.last().map_or(1, |(top, h)| top + h);
    let mut grid = String::from(
        "<!DOCTYPE html><html><head><style>body{margin:0;background:#fff}\
         div{position:absolute;left:0;overflow:hidden}svg{width:100%;height:100%}</style></head><body>",
    );
    for (svg, (top, height)) in svgs.iter().zip(&boxes) {
        grid.push_str(&format!(
            "<div style=\"top:{top}px;width:{CELL_W}px;height:{height}px\">{svg}</div>"
        ));
    }
    grid.push_str("</body></html>");
    let grid_path = dir.path().join("grid.html");
    std::fs::write(&grid_path, grid).unwrap();
    let grid_png = dir.path().join("grid.png");
    run(
        chromium,
        &profile,
        &[
            format!("--window-size={CELL_W},{total}"),
            format!("--screenshot={}", grid_png.display()),
            format!("file://{}", grid_path.display()),
        ],
    );
    let (grid_pixels, width) = pixels(&grid_png);
    let figure_ink = boxes
        .iter()
        .map(|&(top, height)| {
            let mut ink = 0usize;
            for y in top..top + height {
                for x in 0..CELL_W {
                    if grid_pixels.get((y * width + x) as usize).is_some_and(inked) {
                        ink += 1;
                    }
                }
            }
            ink as f64 / f64::from(CELL_W * height.max(1))
        })
        .collect();
    Rendered {
        figures: svgs.len(),
        figure_ink,
        page_ink,
        console,
    }
}

/// Asserts that the page and every one of at least `min_figures` figures rendered, with
/// nothing on the console.
pub fn assert_renders(chromium: &Path, report: &Path, min_figures: usize) -> Rendered {
    let r = render(chromium, report);
    assert!(r.figures >= min_figures, "{} figures: {r:?}", r.figures);
    assert!(r.page_ink > 0.01, "the page's first screen is blank: {r:?}");
    for (k, ink) in r.figure_ink.iter().enumerate() {
        assert!(*ink > 0.01, "figure {} is blank ({ink}): {r:?}", k + 1);
    }
    assert!(r.console.is_empty(), "console: {:?}", r.console);
    r
}
