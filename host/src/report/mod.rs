//! The readable reports of `--report DIR`: one self-contained `report.html` per run
//! ([`html`]), its figures drawn by [`charts`] (and by the diagnosis's and redundancy's own
//! plots), written whole or not at all beside the command's other report files.

pub mod charts;
pub mod html;
pub mod pages;

pub use html::{Cell, Figure, HtmlReport, Section, Table};

use crate::diagnose::report::ReportFile;

/// The name of the HTML report in a report folder.
pub const REPORT_HTML: &str = "report.html";

/// The report as the `report.html` file of a report folder.
pub fn html_file(report: &HtmlReport) -> ReportFile {
    ReportFile {
        name: REPORT_HTML.into(),
        bytes: report.render().into_bytes(),
    }
}

/// Writes `report` as `dir/report.html`, whole or not at all, creating `dir`.
pub fn write_html(
    dir: &std::path::Path,
    report: &HtmlReport,
) -> Result<(), crate::diagnose::report::ReportError> {
    crate::diagnose::report::write_files(dir, &[html_file(report)])
}
