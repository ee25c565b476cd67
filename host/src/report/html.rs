//! The one self-contained HTML document every `--report DIR` writes as `report.html`: a
//! summary a person can act on at the top, then sections of prose, tables and figures. The
//! figures are SVG inlined in the page, the style sheet is in its head, and there is no
//! script and no link to anything outside the file, so it opens from disk anywhere, offline.
//!
//! Numbers in tables are written with 4 significant digits ([`significant`]) and powers of
//! ten as superscripts, never as `-1.7054e1` or with seventeen digits; each column states
//! its unit in its header.

use std::fmt::Write as _;

/// Significant digits of every number a report prints.
pub const SIGNIFICANT_DIGITS: usize = 4;

/// A whole report: its title, the summary lines at its top, and its sections in order.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct HtmlReport {
    pub title: String,
    /// What a reader should take away and act on, one line each (plain text).
    pub summary: Vec<String>,
    pub sections: Vec<Section>,
}

/// A section: a heading, paragraphs, tables and figures, in that order.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Section {
    pub heading: String,
    /// Plain-text paragraphs (escaped when rendered).
    pub paragraphs: Vec<String>,
    pub tables: Vec<Table>,
    pub figures: Vec<Figure>,
}

/// A table: a caption, column headers (each with its unit) and rows of cells.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Table {
    pub caption: String,
    pub header: Vec<String>,
    pub rows: Vec<Vec<Cell>>,
}

/// One cell of a table.
#[derive(Debug, Clone, PartialEq)]
pub enum Cell {
    Text(String),
    /// A number, written with [`SIGNIFICANT_DIGITS`] digits.
    Number(f64),
    /// An interval `[lo, hi]`, each end with [`SIGNIFICANT_DIGITS`] digits.
    Interval(f64, f64),
    /// A value with its 1-sigma, `v ± s`.
    PlusMinus(f64, f64),
}

impl From<&str> for Cell {
    fn from(text: &str) -> Self {
        Cell::Text(text.to_string())
    }
}
impl From<String> for Cell {
    fn from(text: String) -> Self {
        Cell::Text(text)
    }
}
impl From<f64> for Cell {
    fn from(value: f64) -> Self {
        Cell::Number(value)
    }
}

/// A figure: an SVG document (as plotters writes it) and its caption.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Figure {
    pub caption: String,
    pub svg: String,
}

impl Section {
    /// An empty section under `heading`.
    pub fn new(heading: impl Into<String>) -> Self {
        Self {
            heading: heading.into(),
            ..Default::default()
        }
    }
    /// Adds a paragraph.
    pub fn paragraph(mut self, text: impl Into<String>) -> Self {
        self.paragraphs.push(text.into());
        self
    }
    /// Adds a figure when there is one (a plot with nothing to draw is left out).
    pub fn figure(mut self, caption: impl Into<String>, svg: Option<String>) -> Self {
        if let Some(svg) = svg {
            self.figures.push(Figure {
                caption: caption.into(),
                svg,
            });
        }
        self
    }
    /// Adds a table.
    pub fn table(mut self, table: Table) -> Self {
        self.tables.push(table);
        self
    }
}

/// The mantissa and power of ten of `value` rounded to `digits` significant digits, the
/// mantissa as text; the exponent is None where the plain decimal form is as short
/// (0.001 <= |value| < 100 000, and zero).
pub fn significant_parts(value: f64, digits: usize) -> (String, Option<i32>) {
    if !value.is_finite() {
        return (format!("{value}"), None);
    }
    if value == 0.0 {
        return ("0".into(), None);
    }
    let digits = digits.max(1);
    // The exponent after rounding: 9.9996 to 4 digits is 10.00, one decade up.
    let rounded: f64 = format!("{value:.*e}", digits - 1).parse().unwrap_or(value);
    let exponent = rounded.abs().log10().floor() as i32;
    if (-3..5).contains(&exponent) {
        let decimals = (digits as i32 - 1 - exponent).max(0) as usize;
        return (format!("{rounded:.decimals$}"), None);
    }
    let mantissa = rounded / 10f64.powi(exponent);
    (format!("{mantissa:.*}", digits - 1), Some(exponent))
}

/// `value` with `digits` significant digits as plain text: `0.01039`, `1.234e-5`.
pub fn significant(value: f64, digits: usize) -> String {
    match significant_parts(value, digits) {
        (m, None) => m,
        (m, Some(e)) => format!("{m}e{e}"),
    }
}

/// `value` with [`SIGNIFICANT_DIGITS`] digits as HTML: `1.234 × 10<sup>−5</sup>`.
pub fn number_html(value: f64) -> String {
    match significant_parts(value, SIGNIFICANT_DIGITS) {
        (m, None) => m.replace('-', "\u{2212}"),
        (m, Some(e)) => format!(
            "{} × 10<sup>{}</sup>",
            m.replace('-', "\u{2212}"),
            e.to_string().replace('-', "\u{2212}")
        ),
    }
}

/// Text with `&`, `<`, `>` and `"` escaped for HTML.
pub fn escape(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            c => out.push(c),
        }
    }
    out
}

/// A number in e notation inside text (`2.89e-4`, `1e-6`) written as a power of ten; other
/// text as is. A number starts where the text before it is not a letter, digit, `_` or `.`
/// (so `omega_dot_e2` stays), and its mantissa has at least one digit.
fn powers_of_ten(text: &str) -> String {
    let b = text.as_bytes();
    let mut out = String::with_capacity(text.len());
    let mut k = 0;
    let mut copied = 0;
    while k < b.len() {
        let boundary =
            k == 0 || !(b[k - 1].is_ascii_alphanumeric() || b[k - 1] == b'_' || b[k - 1] == b'.');
        if boundary
            && (b[k].is_ascii_digit()
                || (b[k] == b'-' && b.get(k + 1).is_some_and(u8::is_ascii_digit)))
        {
            let start = k;
            let mut j = k + usize::from(b[k] == b'-');
            while j < b.len() && (b[j].is_ascii_digit() || b[j] == b'.') {
                j += 1;
            }
            let mantissa_end = j;
            if j < b.len() && b[j] == b'e' {
                let mut e = j + 1;
                if e < b.len() && (b[e] == b'-' || b[e] == b'+') {
                    e += 1;
                }
                let digits = e;
                while e < b.len() && b[e].is_ascii_digit() {
                    e += 1;
                }
                let ends_word = e == b.len() || !b[e].is_ascii_alphanumeric();
                if e > digits && ends_word {
                    out.push_str(&text[copied..start]);
                    let mantissa = &text[start..mantissa_end];
                    let exponent = text[j + 1..e].trim_start_matches('+');
                    if mantissa.trim_start_matches('-') == "1" {
                        out.push_str(&format!(
                            "{}10<sup>{}</sup>",
                            &mantissa[..mantissa.len() - 1],
                            exponent.replace('-', "\u{2212}")
                        ));
                    } else {
                        out.push_str(&format!(
                            "{} × 10<sup>{}</sup>",
                            mantissa,
                            exponent.replace('-', "\u{2212}")
                        ));
                    }
                    copied = e;
                    k = e;
                    continue;
                }
            }
            k = mantissa_end.max(k + 1);
            continue;
        }
        k += 1;
    }
    out.push_str(&text[copied..]);
    out
}

/// Plain text as HTML: escaped, numbers in e notation as powers of ten.
pub fn text_html(text: &str) -> String {
    powers_of_ten(&escape(text))
}

fn cell_html(cell: &Cell) -> String {
    match cell {
        Cell::Text(t) => text_html(t),
        Cell::Number(v) => number_html(*v),
        Cell::Interval(lo, hi) => format!("[{}, {}]", number_html(*lo), number_html(*hi)),
        Cell::PlusMinus(v, s) => format!("{} ± {}", number_html(*v), number_html(*s)),
    }
}

/// An SVG document as an element to inline: without the XML declaration plotters writes,
/// and scaled to the page's width by its view box.
fn inline_svg(svg: &str) -> String {
    let body = match svg.find("<svg") {
        Some(start) => &svg[start..],
        None => svg,
    };
    body.replacen("<svg", "<svg class=\"figure\" role=\"img\"", 1)
}

const STYLE: &str = "body{font-family:sans-serif;max-width:1150px;margin:2em auto;padding:0 1em;\
color:#222;line-height:1.45}h1{font-size:1.7em}h2{margin-top:2em;border-bottom:1px solid #ccc}\
.summary{background:#f3f7fb;border-left:4px solid #1e64c8;padding:.6em 1.2em}\
table{border-collapse:collapse;margin:1em 0;font-size:.92em}caption{text-align:left;\
font-weight:bold;padding:.3em 0}th,td{border:1px solid #ccc;padding:.25em .6em;\
text-align:right}th{background:#f4f4f4}td:first-child,th:first-child{text-align:left}\
figure{margin:1.5em 0}svg.figure{width:100%;height:auto;border:1px solid #eee}\
figcaption{font-size:.92em;color:#444}";

fn table_html(out: &mut String, t: &Table) {
    out.push_str("<table>");
    if !t.caption.is_empty() {
        let _ = write!(out, "<caption>{}</caption>", text_html(&t.caption));
    }
    out.push_str("<thead><tr>");
    for h in &t.header {
        let _ = write!(out, "<th>{}</th>", escape(h));
    }
    out.push_str("</tr></thead><tbody>");
    for row in &t.rows {
        out.push_str("<tr>");
        for cell in row {
            let _ = write!(out, "<td>{}</td>", cell_html(cell));
        }
        out.push_str("</tr>");
    }
    out.push_str("</tbody></table>\n");
}

impl HtmlReport {
    /// The number of figures in the report.
    pub fn figure_count(&self) -> usize {
        self.sections.iter().map(|s| s.figures.len()).sum()
    }

    /// The whole document.
    pub fn render(&self) -> String {
        let mut out = String::new();
        let _ = write!(
            out,
            "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\
             <meta name=\"generator\" content=\"dynacal {}\"><title>{}</title>\
             <style>{STYLE}</style></head><body>\n<h1>{}</h1>\n",
            env!("CARGO_PKG_VERSION"),
            escape(&self.title),
            escape(&self.title)
        );
        if !self.summary.is_empty() {
            out.push_str("<div class=\"summary\"><ul>");
            for line in &self.summary {
                let _ = write!(out, "<li>{}</li>", text_html(line));
            }
            out.push_str("</ul></div>\n");
        }
        let mut figure_number = 0;
        for section in &self.sections {
            let _ = writeln!(out, "<h2>{}</h2>", escape(&section.heading));
            for p in &section.paragraphs {
                let _ = writeln!(out, "<p>{}</p>", text_html(p));
            }
            for t in &section.tables {
                table_html(&mut out, t);
            }
            for f in &section.figures {
                figure_number += 1;
                let _ = writeln!(
                    out,
                    "<figure id=\"fig{figure_number}\">{}<figcaption>Fig. {figure_number}. {}\
                     </figcaption></figure>",
                    inline_svg(&f.svg),
                    text_html(&f.caption)
                );
            }
        }
        out.push_str("</body></html>\n");
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_have_four_significant_digits_and_no_e_notation_in_html() {
        assert_eq!(significant(-0.010386969759412643, 4), "-0.01039");
        assert_eq!(significant(-17.054, 4), "-17.05");
        assert_eq!(significant(9.99961, 4), "10.00");
        assert_eq!(significant(123456.0, 4), "1.235e5");
        assert_eq!(significant(2.5e-7, 4), "2.500e-7");
        assert_eq!(significant(0.0, 4), "0");
        assert_eq!(significant(0.0009999, 3), "0.00100");
        assert_eq!(significant(0.00099949, 3), "9.99e-4");
        assert_eq!(
            number_html(-1.7054e-5),
            "\u{2212}1.705 × 10<sup>\u{2212}5</sup>"
        );
        assert!(!number_html(-17.054).contains('e'));
    }

    #[test]
    fn e_notation_in_text_becomes_powers_of_ten_and_words_stay() {
        assert_eq!(
            text_html("omega_dot_y -1.74e-4 (t -2.07)*; p < 1e-6; x2e3 and 3e"),
            "omega_dot_y \u{2212}1.74 × 10<sup>\u{2212}4</sup> (t -2.07)*; p &lt; 10<sup>\u{2212}6</sup>; x2e3 and 3e"
                .replace("\u{2212}1.74", "-1.74")
        );
        assert_eq!(text_html("2.5e+3 m"), "2.5 × 10<sup>3</sup> m");
    }

    #[test]
    fn a_report_inlines_its_figures_escapes_its_text_and_links_nothing_outside() {
        let svg = "<?xml version=\"1.0\"?>\n<svg width=\"10\" height=\"10\" viewBox=\"0 0 10 10\" \
                   xmlns=\"http://www.w3.org/2000/svg\"><rect width=\"5\" height=\"5\"/></svg>";
        let report = HtmlReport {
            title: "a <b> & c".into(),
            summary: vec!["gz: scale factor".into()],
            sections: vec![Section::new("S")
                .paragraph("x < y")
                .table(Table {
                    caption: "T".into(),
                    header: vec!["p".into(), "value (rad/s)".into()],
                    rows: vec![vec!["a".into(), Cell::Interval(-1e-6, 2.0)]],
                })
                .figure("one", Some(svg.into()))
                .figure("none", None)],
        };
        let html = report.render();
        assert_eq!(report.figure_count(), 1);
        assert!(html.contains("<title>a &lt;b&gt; &amp; c</title>"));
        assert!(html.contains("<p>x &lt; y</p>"));
        assert!(html.contains("<svg class=\"figure\" role=\"img\" width"));
        assert!(!html.contains("<?xml"));
        assert!(html.contains("10<sup>\u{2212}6</sup>"));
        assert!(!html.contains("<script") && !html.contains("src=") && !html.contains("href="));
        assert_eq!(html.matches("<figure").count(), 1);
    }
}
