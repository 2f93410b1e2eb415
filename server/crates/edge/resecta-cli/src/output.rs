//! Output conventions: one JSON object on stdout with `--json`, progress on stderr when a person
//! watches.

use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;

use crate::error::CliError;

/// Milliseconds since `since`.
pub fn ms(since: Instant) -> f64 {
    since.elapsed().as_secs_f64() * 1e3
}

/// Prints `value` as one JSON object on stdout.
pub fn print_json<T: Serialize>(value: &T) -> Result<(), CliError> {
    let s =
        serde_json::to_string_pretty(value).map_err(|e| CliError::Failed(format!("JSON: {e}")))?;
    let mut out = std::io::stdout().lock();
    writeln!(out, "{s}").map_err(|e| CliError::Failed(format!("stdout: {e}")))
}

/// A spinner with a step message on a terminal; hidden when stderr is piped or with `--json`.
pub fn progress(json: bool) -> ProgressBar {
    if json || !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new_spinner();
    if let Ok(style) = ProgressStyle::with_template("{spinner} {elapsed:>4} {msg}") {
        pb.set_style(style);
    }
    pb.enable_steady_tick(Duration::from_millis(100));
    pb
}

/// A bar counting `len` steps on a terminal; hidden when stderr is piped or with `--json`.
pub fn counter(json: bool, len: u64, unit: &str) -> ProgressBar {
    if json || !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(len);
    let template = format!("{{bar:30}} {{pos}}/{{len}} {unit} {{elapsed:>4}} {{msg}}");
    if let Ok(style) = ProgressStyle::with_template(&template) {
        pb.set_style(style);
    }
    pb
}

/// Creates `dir` and returns a writer of named files in it (errors name the path).
pub fn files_in(dir: &Path) -> Result<impl Fn(&str, &[u8]) -> Result<PathBuf, CliError>, CliError> {
    std::fs::create_dir_all(dir)
        .map_err(|e| CliError::Failed(format!("{}: {e}", dir.display())))?;
    Ok(move |name: &str, bytes: &[u8]| {
        let p = dir.join(name);
        std::fs::write(&p, bytes).map_err(|e| CliError::Failed(format!("{}: {e}", p.display())))?;
        Ok(p)
    })
}

/// Writes `figure` as `STEM.svg` and `STEM.png` with `write` (a [`files_in`] writer).
pub fn write_figure(
    write: &impl Fn(&str, &[u8]) -> Result<PathBuf, CliError>,
    stem: &str,
    figure: &resecta_plot::Figure,
) -> Result<[PathBuf; 2], CliError> {
    let failed = |e: resecta_plot::PlotError| CliError::Failed(format!("plot {stem}: {e}"));
    let svg = figure.to_svg().map_err(failed)?;
    let png = figure.to_png().map_err(failed)?;
    Ok([
        write(&format!("{stem}.svg"), svg.as_bytes())?,
        write(&format!("{stem}.png"), &png)?,
    ])
}
