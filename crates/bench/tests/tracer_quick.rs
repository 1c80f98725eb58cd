//! The quick mode of `pathfarm bench` (estimator study and lecture experiments) as a test: the
//! invariants the study relies on, on the scenes whose every estimator must converge in its
//! budget. Quick mode renders fixed sample counts with a fixed seed, so the numbers asserted here
//! are the same on every run and every machine.

use pathfarm_bench::{BenchOptions, BenchResults};
use std::path::PathBuf;

fn run_quick() -> (BenchResults, PathBuf) {
    let root = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("bench-quick");
    let out = root.join("out");
    let _ = std::fs::remove_dir_all(&out);
    let mut opts = BenchOptions::new(out.clone(), true);
    opts.scenes = vec!["cornell".into(), "furnace".into()];
    opts.scenes_dir = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes"));
    opts.cache_dir = root.join("cache");
    opts.threads = 2;
    let results = pathfarm_bench::run(&opts).expect("quick bench");
    (results, out)
}

#[test]
fn quick_study_holds_its_invariants_and_writes_its_report() {
    let (r, out) = run_quick();
    assert_eq!(r.scenes.len(), 2);
    for s in &r.scenes {
        assert_eq!(s.runs.len(), 14, "{}", s.name);
        for x in &s.runs {
            // Every unbiased strategy agrees with the reference within noise.
            assert!(
                x.agrees,
                "{} / {}: image mean {} is {:.2} standard errors from the reference",
                s.name, x.label, x.errors.mean, x.errors.mean_z
            );
            assert_eq!(x.invalid, 0, "{} / {}", s.name, x.label);
            assert_eq!(x.spp, 64);
            assert!(
                x.errors.rel_rmse > 0.0 && x.errors.rel_rmse < 1.0,
                "{} / {}: {:?}",
                s.name,
                x.label,
                x.errors
            );
            assert!(x.samples_per_second > 0.0 && x.rays_per_sample >= 1.0);
            assert!(x.max_sample > 0.0);
            // The error falls as 1/√N for plain Monte Carlo, and no slower with Sobol.
            let slope = x.slope_spp.expect("enough passes for a slope");
            if x.sampler == "independent" {
                assert!(
                    (-0.75..=-0.3).contains(&slope),
                    "{} / {}: error slope {slope:.3}, expected about −0.5",
                    s.name,
                    x.label
                );
            } else {
                assert!(
                    slope <= -0.3,
                    "{} / {}: error slope {slope:.3}",
                    s.name,
                    x.label
                );
            }
            // Errors shrink from the first measured pass to the last.
            let first = x.passes.iter().find(|p| p.spp >= 4).unwrap();
            assert!(
                x.errors.rmse < first.errors.rmse,
                "{} / {}",
                s.name,
                x.label
            );
        }
    }
    // The furnace's reference is exact; the Cornell box's is a rendered one with its noise known.
    let furnace = r.scenes.iter().find(|s| s.name == "furnace").unwrap();
    assert!(furnace.reference.exact && (furnace.reference.mean - 2.0).abs() < 1e-12);
    let cornell = r.scenes.iter().find(|s| s.name == "cornell").unwrap();
    assert!(!cornell.reference.exact && cornell.reference.spp == 4096);
    assert!(cornell.reference.noise_rmse > 0.0);

    // The lecture experiments: light sampling beats uniform hemisphere directions at equal
    // samples, cosine beats uniform; more samples, less error; no roulette, more rays.
    let e = r.experiments.as_ref().expect("experiments");
    let (hemi, light) = (&e.hemisphere_vs_light[0], &e.hemisphere_vs_light[1]);
    assert!(hemi.label.starts_with("hemisphere") && light.label.starts_with("light"));
    assert!(
        light.rel_rmse < 0.5 * hemi.rel_rmse,
        "{light:?} vs {hemi:?}"
    );
    let cosine = &e.cosine_vs_hemisphere[0];
    assert!(cosine.rel_rmse < hemi.rel_rmse, "{cosine:?} vs {hemi:?}");
    let l = &e.spp_ladder;
    assert_eq!(
        l.iter().map(|x| x.spp).collect::<Vec<_>>(),
        vec![1, 32, 1024]
    );
    assert!(l[0].rmse > l[1].rmse && l[1].rmse > l[2].rmse);
    let no_rr = &e.roulette[0];
    let auto = e.roulette.last().unwrap();
    assert!(no_rr.label.starts_with("no RR") && auto.label.starts_with("auto"));
    assert!(no_rr.rays_per_sample > auto.rays_per_sample);

    // The files: report, JSON that reads back, SVG charts and PNG images it links.
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    for needle in [
        "## Summary",
        "## Scene `cornell`",
        "## Scene `furnace`",
        "Uniform hemisphere against light-area",
        "no RR",
    ] {
        assert!(md.contains(needle), "report.md lacks {needle:?}");
    }
    let mut linked = 0;
    for part in md.split("](").skip(1) {
        let target = &part[..part.find(')').unwrap()];
        let bytes = std::fs::read(out.join(target)).unwrap_or_else(|e| panic!("{target}: {e}"));
        if target.ends_with(".svg") {
            assert!(bytes.starts_with(b"<svg"), "{target}");
        } else {
            assert!(target.ends_with(".png"), "{target}");
            image::load_from_memory(&bytes).unwrap_or_else(|e| panic!("{target}: {e}"));
        }
        linked += 1;
    }
    assert!(linked >= 2 * 3 + 7, "only {linked} linked files");
    let json: BenchResults =
        serde_json::from_slice(&std::fs::read(out.join("results.json")).unwrap()).unwrap();
    assert_eq!(json.scenes.len(), 2);
}
