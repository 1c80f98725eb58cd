//! `report.md` and its charts.

use crate::chart::{line_chart, ChartSpec, Series};
use crate::error::BenchError;
use crate::experiments::{Entry, Experiments};
use crate::study::{budget_ladder, RunResult, AGREEMENT_Z};
use crate::{BenchResults, SceneResult};
use std::fmt::Write as _;
use std::path::Path;

fn f(v: f64, digits: usize) -> String {
    if v.is_finite() {
        format!("{v:.digits$}")
    } else {
        "∞".into()
    }
}

/// Engineering-style: 3 significant digits with k/M/G.
pub(crate) fn si(v: f64) -> String {
    if !v.is_finite() {
        return "∞".into();
    }
    let (d, suffix) = if v >= 1e9 {
        (v / 1e9, " G")
    } else if v >= 1e6 {
        (v / 1e6, " M")
    } else if v >= 1e3 {
        (v / 1e3, " k")
    } else {
        (v, " ")
    };
    let s = if d >= 100.0 {
        format!("{d:.0}")
    } else if d >= 10.0 {
        format!("{d:.1}")
    } else {
        format!("{d:.2}")
    };
    format!("{s}{}", suffix.trim_end())
}

/// An efficiency; "–" when the error was below what the reference can resolve.
fn eff(v: Option<f64>) -> String {
    v.map_or("–".into(), si)
}

/// A relative RMSE, or a note when the error is below what the reference can resolve (its own
/// noise was subtracted and nothing measurable was left).
fn rel_err(rmse: f64, rel_rmse: f64) -> String {
    if rmse > 0.0 {
        pct(rel_rmse)
    } else {
        "below the reference's noise".into()
    }
}

pub(crate) fn pct(v: f64) -> String {
    format!("{:.2}%", v * 100.0)
}

fn slope(s: Option<f64>) -> String {
    s.map_or("–".into(), |v| format!("{v:.2}"))
}

/// Rel. RMSE against time for the runs `pick` selects, with a 1/√t line through the first.
fn error_chart(
    out_dir: &Path,
    file: &str,
    title: &str,
    runs: &[&RunResult],
) -> Result<String, BenchError> {
    let mut series: Vec<Series> = runs
        .iter()
        .map(|r| {
            Series::new(
                r.label.clone(),
                r.passes
                    .iter()
                    .map(|p| (p.seconds, p.errors.rel_rmse))
                    .collect(),
            )
        })
        .collect();
    if let Some(anchor) = runs.first().and_then(|r| {
        r.passes
            .iter()
            .find(|p| p.errors.rel_rmse > 0.0 && p.seconds > 0.0)
            .zip(r.passes.last())
    }) {
        let (a, last) = anchor;
        let k = a.errors.rel_rmse * a.seconds.sqrt();
        series.push(Series::reference(
            "∝ 1/√t",
            vec![
                (a.seconds, k / a.seconds.sqrt()),
                (last.seconds, k / last.seconds.sqrt()),
            ],
        ));
    }
    let rel = format!("charts/{file}.svg");
    line_chart(
        &out_dir.join(&rel),
        &ChartSpec::log_log(title, "rendering time (s)", "relative RMSE"),
        &series,
    )?;
    Ok(rel)
}

fn scene_section(
    out: &mut String,
    s: &SceneResult,
    r: &BenchResults,
    dir: &Path,
) -> Result<(), BenchError> {
    let _ = writeln!(out, "\n## Scene `{}`\n\n{}\n", s.name, s.description);
    let reference = if s.reference.exact {
        format!("exact (mean luminance {})", f(s.reference.mean, 4))
    } else {
        format!(
            "the project's own render, MIS with independent samples, {} spp{} (mean luminance {}; its own noise, RMS {} = {} of the mean, is subtracted from every MSE)",
            s.reference.spp,
            if s.reference.cached { ", from the cache" } else { "" },
            f(s.reference.mean, 4),
            f(s.reference.noise_rmse, 5),
            pct(s.reference.noise_rmse / s.reference.mean.max(1e-12)),
        )
    };
    let _ = writeln!(
        out,
        "{} triangles, loaded and built in {} s; {}×{} pixels. Reference: {}.\n",
        s.triangles,
        f(s.build_seconds, 2),
        s.width,
        s.height,
        reference
    );
    let auto = |sampler: &str| -> Vec<&RunResult> {
        s.runs
            .iter()
            .filter(|x| x.sampler == sampler && x.rr == "auto")
            .collect()
    };
    let sobol = error_chart(
        dir,
        &format!("{}-strategies-sobol", s.name),
        &format!("{}: strategies, Sobol", s.name),
        &auto("sobol"),
    )?;
    let independent = error_chart(
        dir,
        &format!("{}-strategies-independent", s.name),
        &format!("{}: strategies, independent", s.name),
        &auto("independent"),
    )?;
    let rr: Vec<&RunResult> = s
        .runs
        .iter()
        .filter(|x| x.strategy == "mis" && x.sampler == "sobol")
        .collect();
    let roulette = error_chart(
        dir,
        &format!("{}-roulette", s.name),
        &format!("{}: Russian roulette (MIS, Sobol)", s.name),
        &rr,
    )?;
    let _ = writeln!(
        out,
        "| Sobol | independent | roulette |\n|---|---|---|\n| ![{0} Sobol]({1}) | ![{0} independent]({2}) | ![{0} roulette]({3}) |\n",
        s.name, sobol, independent, roulette
    );
    let _ = writeln!(
        out,
        "| configuration | spp | time (s) | samples/s | rays/s | rays/sample | RMSE | rel. RMSE | relMSE | 1/(MSE·t) | slope (t) | slope (spp) | max sample | NaN/Inf | z | within noise |"
    );
    let _ = writeln!(
        out,
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|:---:|"
    );
    for x in &s.runs {
        let _ = writeln!(
            out,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            x.label,
            x.spp,
            f(x.seconds, 2),
            si(x.samples_per_second),
            si(x.rays_per_second),
            f(x.rays_per_sample, 2),
            f(x.errors.rmse, 5),
            rel_err(x.errors.rmse, x.errors.rel_rmse),
            f(x.errors.rel_mse, 5),
            eff(x.efficiency),
            slope(x.slope_time),
            slope(x.slope_spp),
            si(x.max_sample),
            x.invalid,
            f(x.errors.mean_z, 2),
            if x.agrees { "yes" } else { "**no**" }
        );
    }
    if r.fixed_spp.is_none() {
        let ladder = budget_ladder(r.time_budget);
        let _ = write!(out, "\nRelative RMSE at equal time:\n\n| configuration |");
        for b in &ladder {
            let _ = write!(out, " {} s |", f(*b, 3));
        }
        let _ = write!(out, "\n|---|");
        for _ in &ladder {
            let _ = write!(out, "---:|");
        }
        let _ = writeln!(out);
        for x in &s.runs {
            let _ = write!(out, "| {} |", x.label);
            for v in &x.at_budgets {
                let _ = write!(out, " {} |", v.map_or("–".into(), pct));
            }
            let _ = writeln!(out);
        }
    }
    Ok(())
}

fn entries_table(out: &mut String, entries: &[Entry]) {
    let _ = writeln!(out, "| | time (s) | rays/sample | RMSE | rel. RMSE | 1/(MSE·t) |\n|---|---:|---:|---:|---:|---:|");
    for e in entries {
        let _ = writeln!(
            out,
            "| {} | {} | {} | {} | {} | {} |",
            e.label,
            f(e.seconds, 3),
            f(e.rays_per_sample, 2),
            f(e.rmse, 5),
            rel_err(e.rmse, e.rel_rmse),
            eff(e.efficiency)
        );
    }
    let _ = writeln!(out);
}

fn images_row(out: &mut String, entries: &[Entry]) {
    let _ = write!(out, "|");
    for e in entries {
        let _ = write!(out, " {} |", e.label);
    }
    let _ = write!(out, "\n|");
    for _ in entries {
        let _ = write!(out, "---|");
    }
    let _ = write!(out, "\n|");
    for e in entries {
        let _ = write!(out, " ![{}]({}) |", e.label, e.image);
    }
    let _ = writeln!(out, "\n");
}

fn experiments_section(out: &mut String, e: &Experiments) {
    let _ = writeln!(
        out,
        "\n## Lecture experiments (`{}`, {}×{}, MIS where not named, Sobol)\n",
        e.scene, e.width, e.height
    );
    let _ = writeln!(
        out,
        "### Uniform hemisphere against light-area sampling, {} samples per pixel each\n",
        e.equal_spp
    );
    images_row(out, &e.hemisphere_vs_light);
    entries_table(out, &e.hemisphere_vs_light);
    let _ = writeln!(
        out,
        "### Cosine-weighted against uniform hemisphere, {} samples per pixel each\n",
        e.equal_spp
    );
    images_row(out, &e.cosine_vs_hemisphere);
    entries_table(out, &e.cosine_vs_hemisphere);
    let _ = writeln!(
        out,
        "### Russian roulette against time and noise, {} samples per pixel\n",
        e.roulette_spp
    );
    let words: Vec<String> = e
        .roulette
        .iter()
        .map(|x| {
            format!(
                "{}: {} s, rel. RMSE {}",
                x.label,
                f(x.seconds, 2),
                pct(x.rel_rmse)
            )
        })
        .collect();
    let _ = writeln!(out, "{}.\n", words.join("; "));
    entries_table(out, &e.roulette);
    let _ = writeln!(out, "### 1, 32 and 1024 samples per pixel\n");
    images_row(out, &e.spp_ladder);
    entries_table(out, &e.spp_ladder);
}

/// The summary: per scene, the most efficient configuration and every estimator that visibly
/// fails (outside the noise, or converging slower than 1/√t).
fn summary(out: &mut String, r: &BenchResults) {
    let _ = writeln!(out, "\n## Summary\n");
    let _ = writeln!(out, "| scene | most efficient | its rel. RMSE | least efficient | failing (|z| ≥ {AGREEMENT_Z}, or error slope above −0.3) |\n|---|---|---:|---|---|");
    for s in &r.scenes {
        let key = |r: &RunResult| r.efficiency.unwrap_or(f64::INFINITY);
        let by_eff = |a: &&RunResult, b: &&RunResult| key(a).total_cmp(&key(b));
        let best = s.runs.iter().max_by(by_eff);
        let worst = s.runs.iter().min_by(by_eff);
        let failing: Vec<String> = s
            .runs
            .iter()
            .filter(|x| !x.agrees || x.slope_time.is_some_and(|v| v > -0.3))
            .map(|x| x.label.clone())
            .collect();
        let _ = writeln!(
            out,
            "| {} | {} | {} | {} | {} |",
            s.name,
            best.map_or("–".into(), |b| b.label.clone()),
            best.map_or("–".into(), |b| pct(b.errors.rel_rmse)),
            worst.map_or("–".into(), |b| b.label.clone()),
            if failing.is_empty() {
                "none".into()
            } else {
                failing.join("; ")
            }
        );
    }
}

/// Writes the charts under `dir/charts/` and returns the Markdown of `report.md`.
pub fn write(r: &BenchResults, dir: &Path) -> Result<String, BenchError> {
    let mut out = String::new();
    let _ = writeln!(out, "# pathfarm bench report\n");
    if !r.command_line.is_empty() {
        let _ = writeln!(out, "Command: `{}`\n", r.command_line);
    }
    let m = &r.machine;
    let _ = writeln!(
        out,
        "Machine: {} ({} logical cores, {} render threads), {}, {}.\n",
        m.cpu, m.logical_cores, m.threads, m.os, m.date
    );
    if !r.scenes.is_empty() {
        let mode = match r.fixed_spp {
            Some(spp) => format!("quick mode: every configuration rendered to {spp} spp in passes of growing sample counts (the same numbers on every run)"),
            None => format!("every configuration rendered in passes of growing sample counts (×1.5) until its time budget of {} s", f(r.time_budget, 2)),
        };
        let _ = writeln!(
            out,
            "Estimator study: {mode}; seed {}; errors on luminance against the reference after every pass. \
             *rel. RMSE* is RMSE / reference mean; *relMSE* the mean of (x − r)² / (r² + 0.01); \
             *1/(MSE·t)* the efficiency; *slope* the fitted exponent of RMSE against time or spp (passes of ≥ 4 spp; −0.5 for plain Monte Carlo); \
             *max sample* the largest single-sample luminance; *z* the image mean's distance from the reference's in combined standard errors.",
            r.seed
        );
        summary(&mut out, r);
        for s in &r.scenes {
            scene_section(&mut out, s, r, dir)?;
        }
    }
    if let Some(e) = &r.experiments {
        experiments_section(&mut out, e);
    }
    Ok(out)
}
