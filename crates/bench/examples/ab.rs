//! A same-time A/B of two builds of the `throughput` example: `cargo run --release -p
//! pathfarm-bench --example ab -- [--rounds N] [--images-differ] BINARY_A BINARY_B [SCENE THREADS
//! SPP]`.
//!
//! This VM's speed drifts by ±10–30 % within minutes, so two runs one after the other do not
//! compare. Here both binaries run at the same time, each pinned to a core of its own (`taskset`,
//! from util-linux), with the cores swapped every round; a round's ratio is A's samples/s over
//! B's. The two cores of this VM need not be equally fast (one was 20 % slower than the other on
//! November 25), so rounds go in pairs, one on each assignment of cores, and a pair's ratio is the
//! geometric mean of its two: the cores' difference cancels. The result is the mean of the
//! pairs' ratios ± its standard error. Both must print the same hash (the same image): an
//! optimisation that changes a bit fails the comparison, unless `--images-differ` says the change
//! is meant to change the image (a fix), when only the speeds are compared. The usual arguments
//! are `cornell 1 32` and `sphere330k 1 16` (one thread each, so the two runs do not share a core).
//!
//! Typical use: build the baseline, copy `target/release/examples/throughput` aside, build the
//! change, then `ab target/release/examples/throughput /tmp/throughput-base cornell 1 32`.

use std::process::{Command, Stdio};

/// What one run of the `throughput` example printed.
#[derive(Debug, PartialEq)]
struct Run {
    samples_per_second: f64,
    hash: String,
}

/// Reads `… X M samples/s, … hash H` off a line of the `throughput` example.
fn parse(out: &str) -> Option<Run> {
    let line = out.lines().find(|l| l.contains(" M samples/s"))?;
    let before = line.split(" M samples/s").next()?;
    let value = before.rsplit([' ', ',']).next()?.parse().ok()?;
    let hash = line.split("hash ").nth(1)?.trim().to_string();
    Some(Run {
        samples_per_second: value,
        hash,
    })
}

/// Each pair of consecutive rounds' ratios (cores swapped between them) as one ratio, their
/// geometric mean: a core that is faster than the other multiplies one ratio and divides the
/// other by the same factor.
fn pair_ratios(ratios: &[f64]) -> Vec<f64> {
    ratios
        .chunks_exact(2)
        .map(|pair| (pair[0] * pair[1]).sqrt())
        .collect()
}

/// The mean of `xs` and its standard error (0 for a single value).
fn mean_and_error(xs: &[f64]) -> (f64, f64) {
    let n = xs.len() as f64;
    let mean = xs.iter().sum::<f64>() / n;
    if xs.len() < 2 {
        return (mean, 0.0);
    }
    let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, (var / n).sqrt())
}

/// Starts `binary` with `args` pinned to `core`.
fn start(binary: &str, core: usize, args: &[String]) -> std::io::Result<std::process::Child> {
    Command::new("taskset")
        .arg("-c")
        .arg(core.to_string())
        .arg(binary)
        .args(args)
        .stdout(Stdio::piped())
        .spawn()
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let mut rounds: usize = 8;
    let mut images_differ = false;
    loop {
        match args.first().map(String::as_str) {
            Some("--rounds") => {
                rounds = args.get(1).ok_or("--rounds needs a count")?.parse()?;
                args.drain(..2);
            }
            Some("--images-differ") => {
                images_differ = true;
                args.remove(0);
            }
            _ => break,
        }
    }
    // Whole pairs of rounds, at least one.
    let rounds = rounds.max(2).next_multiple_of(2);
    if args.len() < 2 {
        return Err(
            "usage: ab [--rounds N] [--images-differ] BINARY_A BINARY_B [SCENE THREADS SPP]".into(),
        );
    }
    let (a, b) = (args[0].clone(), args[1].clone());
    let rest: Vec<String> = if args.len() > 2 {
        args[2..].to_vec()
    } else {
        ["cornell", "1", "32"].map(String::from).to_vec()
    };
    let mut ratios = Vec::with_capacity(rounds);
    for round in 0..rounds {
        let (core_a, core_b) = if round % 2 == 0 { (0, 1) } else { (1, 0) };
        let (pa, pb) = (start(&a, core_a, &rest)?, start(&b, core_b, &rest)?);
        let (oa, ob) = (pa.wait_with_output()?, pb.wait_with_output()?);
        let parse_run = |name: &str, out: &std::process::Output| {
            let text = String::from_utf8_lossy(&out.stdout);
            parse(&text).ok_or_else(|| format!("{name} printed no throughput line: {text}"))
        };
        let (ra, rb) = (parse_run(&a, &oa)?, parse_run(&b, &ob)?);
        let ratio = ra.samples_per_second / rb.samples_per_second;
        println!(
            "round {round}: A {:.3} B {:.3} M samples/s, ratio {ratio:.3}",
            ra.samples_per_second, rb.samples_per_second
        );
        if ra.hash != rb.hash && !images_differ {
            return Err(format!("the images differ: hash {} against {}", ra.hash, rb.hash).into());
        }
        ratios.push(ratio);
    }
    let (mean, error) = mean_and_error(&pair_ratios(&ratios));
    println!(
        "A/B over {rounds} rounds ({} pairs): {:+.1} % ± {:.1} ({})",
        rounds / 2,
        (mean - 1.0) * 100.0,
        error * 100.0,
        if images_differ {
            "images may differ"
        } else {
            "same hash"
        }
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_the_throughput_line() {
        let out = "cornell: 1 threads, 32 spp: 1.234 s, 1.699 M samples/s, 8.94 M rays/s, hash \
                   e042e78ee818bf44\n";
        assert_eq!(
            parse(out),
            Some(Run {
                samples_per_second: 1.699,
                hash: "e042e78ee818bf44".into()
            })
        );
        assert_eq!(parse("no such line"), None);
    }

    #[test]
    fn mean_and_standard_error() {
        let (m, e) = mean_and_error(&[1.0, 1.2, 0.8, 1.0]);
        assert!((m - 1.0).abs() < 1e-12);
        // Sample variance 0.08/3; standard error sqrt(0.08/3/4).
        assert!((e - (0.08f64 / 12.0).sqrt()).abs() < 1e-12, "{e}");
        assert_eq!(mean_and_error(&[2.0]), (2.0, 0.0));
    }

    /// A core 20 % faster than the other cancels within a pair of rounds.
    #[test]
    fn pairs_cancel_the_cores_difference() {
        let true_ratio = 1.05;
        let ratios = [
            true_ratio * 1.2,
            true_ratio / 1.2,
            true_ratio * 1.2,
            true_ratio / 1.2,
        ];
        let pairs = pair_ratios(&ratios);
        assert_eq!(pairs.len(), 2);
        for p in pairs {
            assert!((p - true_ratio).abs() < 1e-12, "{p}");
        }
        assert_eq!(
            pair_ratios(&[1.0, 1.0, 1.0]).len(),
            1,
            "a lone last round is left out"
        );
    }
}
