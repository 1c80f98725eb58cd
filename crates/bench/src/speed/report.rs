//! The verdict on each target and `speed.md`.

use super::{
    CornellResult, MillionResult, SpeedResults, SphereResult, Target, Throughput, REPEATS,
    SPHERE_SPP, TARGET_10PCT_SECONDS, TARGET_330K_BUILD_SECONDS, TARGET_330K_SAMPLES_PER_S,
    TARGET_5PCT_SECONDS, TARGET_CORNELL_SAMPLES_PER_S, TARGET_MILLION_RSS_MIB, THROUGHPUT_SPP,
};
use crate::report::{pct, si};
use std::fmt::Write as _;

/// Each target with its measurement and whether it was met.
pub(super) fn targets(m: &MillionResult, s: &SphereResult, c: &CornellResult) -> Vec<Target> {
    let samples = |v: f64| format!("{} samples/s", si(v));
    let secs = |v: f64| format!("{v:.3} s");
    let mut t = vec![Target {
        what: format!("Cornell throughput ({THROUGHPUT_SPP} spp, best of {REPEATS})"),
        goal: format!("≥ {}", samples(TARGET_CORNELL_SAMPLES_PER_S)),
        measured: samples(c.throughput.samples_per_second),
        met: Some(c.throughput.samples_per_second >= TARGET_CORNELL_SAMPLES_PER_S),
    }];
    for (level, goal) in [(0.10, TARGET_10PCT_SECONDS), (0.05, TARGET_5PCT_SECONDS)] {
        let (measured, met) = match &c.convergence {
            None => ("not measured (no reference)".to_string(), None),
            Some(cv) => {
                let reached = if level == 0.10 {
                    cv.seconds_to_10pct
                } else {
                    cv.seconds_to_5pct
                };
                match reached {
                    Some(v) => (secs(v), Some(v < goal)),
                    None => {
                        let last = cv.passes.last().map_or(0.0, |p| p.seconds);
                        (format!("not reached in {}", secs(last)), Some(false))
                    }
                }
            }
        };
        t.push(Target {
            what: format!("Cornell rel. RMSE ≤ {:.0} %", level * 100.0),
            goal: format!("< {goal} s"),
            measured,
            met,
        });
    }
    t.push(Target {
        what: format!("330k triangles: BVH build (best of {REPEATS})"),
        goal: format!("< {TARGET_330K_BUILD_SECONDS} s"),
        measured: secs(s.build_seconds),
        met: Some(s.build_seconds < TARGET_330K_BUILD_SECONDS),
    });
    t.push(Target {
        what: format!("330k triangles: throughput ({SPHERE_SPP} spp, best of {REPEATS})"),
        goal: format!("≥ {}", samples(TARGET_330K_SAMPLES_PER_S)),
        measured: samples(s.render.samples_per_second),
        met: Some(s.render.samples_per_second >= TARGET_330K_SAMPLES_PER_S),
    });
    t.push(Target {
        what: "Million triangles: peak resident memory".into(),
        goal: "< 1 GiB".into(),
        measured: m
            .peak_rss_mib
            .map_or("not measured (no /proc)".into(), |v| format!("{v:.0} MiB")),
        met: m.peak_rss_mib.map(|v| v < TARGET_MILLION_RSS_MIB),
    });
    t
}

/// `speed.md`.
pub fn markdown(r: &SpeedResults) -> String {
    let mut out = String::new();
    let _ = writeln!(out, "# pathfarm bench speed\n");
    if !r.command_line.is_empty() {
        let _ = writeln!(out, "Command: `{}`\n", r.command_line);
    }
    let m = &r.machine;
    let _ = writeln!(
        out,
        "Machine: {} ({} logical cores, {} render threads), {}, {}. Every render {}×{}, MIS, \
         Russian roulette auto, unlimited depth, Sobol, seed {}; samples/s counts camera samples \
         (pixels × spp) per second of wall time.\n",
        m.cpu, m.logical_cores, m.threads, m.os, m.date, r.size, r.size, r.seed
    );
    let _ = writeln!(
        out,
        "## Targets\n\n| target | goal | measured | |\n|---|---|---:|---|"
    );
    for t in &r.targets {
        let verdict = match t.met {
            Some(true) => "met",
            Some(false) => "**not met**",
            None => "not measured",
        };
        let _ = writeln!(
            out,
            "| {} | {} | {} | {verdict} |",
            t.what, t.goal, t.measured
        );
    }
    let tp = |t: &Throughput| {
        format!(
            "{} spp in {:.3} s: {} samples/s, {} rays/s",
            t.spp,
            t.seconds,
            si(t.samples_per_second),
            si(t.rays_per_second)
        )
    };
    let mi = &r.million;
    let _ = writeln!(
        out,
        "\n## million: the Cornell box and a displaced sphere, generated in memory\n\n\
         - {} triangles; generated, loaded and built (BVH included) in {:.2} s; the tracer \
         estimates the scene at {:.0} MiB.\n- Render: {}.\n- Peak resident memory: {}. This is \
         `VmHWM` of the whole bench process after that render; the measurement runs first, so \
         nothing else has used more memory before it.",
        mi.triangles,
        mi.build_seconds,
        mi.scene_mib,
        tp(&mi.render),
        mi.peak_rss_mib
            .map_or("not measured (no /proc/self/status)".into(), |v| format!(
                "{v:.0} MiB"
            )),
    );
    let sp = &r.sphere330k;
    let runs: Vec<String> = sp.build_runs.iter().map(|v| format!("{v:.3}")).collect();
    let render_runs: Vec<String> = sp.render_runs.iter().map(|v| format!("{v:.3}")).collect();
    let _ = writeln!(
        out,
        "\n## sphere330k: the Cornell box and a displaced sphere\n\n\
         - {} triangles; `Scene::build` (BVH included, the parts generated beforehand): best \
         {:.3} s (runs of {} s).\n- Render (runs of {} s): best {}.",
        sp.triangles,
        sp.build_seconds,
        runs.join(", "),
        render_runs.join(", "),
        tp(&sp.render),
    );
    let c = &r.cornell;
    let runs: Vec<String> = c
        .throughput_runs
        .iter()
        .map(|v| format!("{v:.3}"))
        .collect();
    let _ = writeln!(
        out,
        "\n## cornell: scenes/cornell.gltf\n\n- Throughput (runs of {} s): best {}.",
        runs.join(", "),
        tp(&c.throughput)
    );
    if let Some(why) = &c.skipped {
        let _ = writeln!(out, "- Error against time: skipped, {why}.");
    }
    if let Some(cv) = &c.convergence {
        let noise = cv.reference_noise.map_or(String::new(), |n| {
            format!(
                " The reference's own noise is {} of its mean (from its standard-error image), \
                 included in every error in quadrature and not subtracted.",
                pct(n)
            )
        });
        let _ = writeln!(
            out,
            "- Error against time, against `{}` (Mitsuba 3, 8192 spp): passes of doubling sample \
             ranges merged exactly into one image; rel. RMSE = RMSE over every pixel and RGB \
             channel / the reference's mean ({:.4}). Time is cumulative render time only.{noise}\n",
            cv.reference, cv.reference_mean
        );
        let _ = writeln!(out, "| spp | seconds | rel. RMSE |\n|---:|---:|---:|");
        for p in &cv.passes {
            let _ = writeln!(
                out,
                "| {} | {:.3} | {} |",
                p.spp,
                p.seconds,
                pct(p.rel_rmse)
            );
        }
        let at = |v: Option<f64>| v.map_or("not reached".into(), |s| format!("{s:.3} s"));
        let _ = writeln!(
            out,
            "\nRel. RMSE first reaches 10 % at {} and 5 % at {} (log–log interpolation between \
             the passes around it).",
            at(cv.seconds_to_10pct),
            at(cv.seconds_to_5pct)
        );
    }
    out
}
