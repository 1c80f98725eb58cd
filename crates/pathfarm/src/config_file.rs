//! The optional TOML configuration file (`--config FILE` or `PATHFARM_CONFIG`).
//!
//! Every setting has one flag, one environment variable and one key in the file, in the table
//! named after the command (`[serve]`, `[worker]`, `[up]`, `[client]`). The precedence is flag,
//! then environment, then file, then default; it is obtained by handing the file's values to clap
//! as environment variables that are not already set, before the command line is parsed, so the
//! one parser applies every rule (types, ranges, lists) to values from all three sources.

use anyhow::{bail, Context, Result};
use std::path::Path;

/// (table, key, environment variable). The key is the flag's long name.
pub const KEYS: &[(&str, &str, &str)] = &[
    ("serve", "listen", "PATHFARM_LISTEN"),
    ("serve", "db", "PATHFARM_DB"),
    ("serve", "client-tokens", "PATHFARM_CLIENT_TOKENS"),
    ("serve", "worker-tokens", "PATHFARM_WORKER_TOKENS"),
    ("serve", "lease-seconds", "PATHFARM_LEASE_SECONDS"),
    ("serve", "max-scene-mib", "PATHFARM_MAX_SCENE_MIB"),
    ("serve", "scene-checks", "PATHFARM_SCENE_CHECKS"),
    (
        "serve",
        "max-scene-triangles",
        "PATHFARM_MAX_SCENE_TRIANGLES",
    ),
    ("serve", "image-cache-mib", "PATHFARM_IMAGE_CACHE_MIB"),
    (
        "serve",
        "header-timeout-seconds",
        "PATHFARM_HEADER_TIMEOUT_SECONDS",
    ),
    ("serve", "keep-alive-seconds", "PATHFARM_KEEP_ALIVE_SECONDS"),
    (
        "serve",
        "body-timeout-seconds",
        "PATHFARM_BODY_TIMEOUT_SECONDS",
    ),
    (
        "serve",
        "body-min-kib-per-second",
        "PATHFARM_BODY_MIN_KIB_PER_SECOND",
    ),
    ("serve", "max-connections", "PATHFARM_MAX_CONNECTIONS"),
    ("serve", "tls-cert", "PATHFARM_TLS_CERT"),
    ("serve", "tls-key", "PATHFARM_TLS_KEY"),
    (
        "serve",
        "max-leases-per-worker",
        "PATHFARM_MAX_LEASES_PER_WORKER",
    ),
    (
        "serve",
        "worker-expiry-seconds",
        "PATHFARM_WORKER_EXPIRY_SECONDS",
    ),
    ("up", "workers", "PATHFARM_WORKERS"),
    ("up", "threads-per-worker", "PATHFARM_THREADS_PER_WORKER"),
    ("up", "port", "PATHFARM_PORT"),
    ("up", "host", "PATHFARM_HOST"),
    ("worker", "server", "PATHFARM_SERVER"),
    ("worker", "token", "PATHFARM_WORKER_TOKEN"),
    ("worker", "threads", "PATHFARM_THREADS"),
    ("worker", "name", "PATHFARM_WORKER_NAME"),
    ("worker", "cache-dir", "PATHFARM_CACHE_DIR"),
    ("worker", "slice-seconds", "PATHFARM_SLICE_SECONDS"),
    ("worker", "slice-samples", "PATHFARM_SLICE_SAMPLES"),
    ("worker", "ca-cert", "PATHFARM_CA_CERT"),
    ("client", "server", "PATHFARM_SERVER"),
    ("client", "token", "PATHFARM_TOKEN"),
    ("client", "ca-cert", "PATHFARM_CA_CERT"),
];

/// Whether `command` reads `key` of `[table]`.
fn reads(command: &str, table: &str, key: &str) -> bool {
    // `up` listens where its own `host` and `port` say, over plain HTTP (its workers are its own
    // processes on the same machine).
    tables_for(command).contains(&table)
        && !(command == "up" && matches!(key, "listen" | "tls-cert" | "tls-key"))
}

/// Which tables a command reads: `up` runs a server too, so it reads `[serve]` as well (all but
/// `listen`).
fn tables_for(command: &str) -> &'static [&'static str] {
    match command {
        "serve" => &["serve"],
        "up" => &["up", "serve"],
        "worker" => &["worker"],
        "submit" | "jobs" | "job" | "cancel" | "pause" | "resume" | "delete" | "priority"
        | "workers" => &["client"],
        _ => &[],
    }
}

/// The `(variable, value)` pairs the file sets for `command`. Every key of every table is checked,
/// so a typo is an error that names it, whichever command runs.
pub fn settings(text: &str, origin: &Path, command: &str) -> Result<Vec<(&'static str, String)>> {
    let doc: toml::Table = text
        .parse()
        .with_context(|| format!("{}: not valid TOML", origin.display()))?;
    let mut out = Vec::new();
    for (table, value) in &doc {
        let Some(entries) = value.as_table() else {
            bail!(
                "{}: `{table}` must be a table ([serve], [up], [worker] or [client])",
                origin.display()
            );
        };
        if !KEYS.iter().any(|(t, _, _)| t == table) {
            bail!(
                "{}: unknown table [{table}] (expected [serve], [up], [worker] or [client])",
                origin.display()
            );
        }
        for (key, value) in entries {
            let Some(&(_, _, var)) = KEYS.iter().find(|(t, k, _)| t == table && k == key) else {
                let known: Vec<&str> = KEYS
                    .iter()
                    .filter(|(t, _, _)| t == table)
                    .map(|(_, k, _)| *k)
                    .collect();
                bail!(
                    "{}: unknown key `{key}` in [{table}] (known: {})",
                    origin.display(),
                    known.join(", ")
                );
            };
            let text = scalar_or_list(value)
                .with_context(|| format!("{}: [{table}] {key}", origin.display()))?;
            if reads(command, table, key) {
                out.push((var, text));
            }
        }
    }
    Ok(out)
}

fn scalar_or_list(v: &toml::Value) -> Result<String> {
    Ok(match v {
        toml::Value::String(s) => s.clone(),
        toml::Value::Integer(i) => i.to_string(),
        toml::Value::Float(f) => f.to_string(),
        toml::Value::Boolean(b) => b.to_string(),
        toml::Value::Array(items) => {
            let parts = items
                .iter()
                .map(scalar_or_list)
                .collect::<Result<Vec<_>>>()?;
            if parts.iter().any(|p| p.contains(',')) {
                bail!("list items cannot contain commas");
            }
            parts.join(",")
        }
        other => bail!(
            "expected a string, number, boolean or list, got {}",
            other.type_str()
        ),
    })
}

/// The subcommands (as `main.rs` names them).
pub(crate) const COMMANDS: &[&str] = &[
    "render", "serve", "worker", "up", "submit", "jobs", "job", "cancel", "pause", "resume",
    "delete", "priority", "workers", "bench", "help",
];

/// The global options that take a value (as `main.rs` declares them).
pub(crate) const GLOBAL_VALUE_OPTIONS: &[&str] = &["--log", "--log-format", "--config"];

/// What `apply` needs from the raw arguments (without the program name): the `--config` value,
/// if any, and the subcommand: the first argument that names one, where an argument that is the
/// value of a global option (`--log-format json`) does not count. `--` ends the options.
fn scan(args: &[String]) -> (Option<std::path::PathBuf>, Option<String>) {
    let mut config = None;
    let mut command = None;
    let mut i = 0;
    while i < args.len() {
        let a = args[i].as_str();
        if a == "--" {
            break;
        }
        if let Some(p) = a.strip_prefix("--config=") {
            config = Some(p.into());
        } else if GLOBAL_VALUE_OPTIONS.contains(&a) {
            if a == "--config" {
                config = args.get(i + 1).map(Into::into);
            }
            i += 1; // its value
        } else if command.is_none() && COMMANDS.contains(&a) {
            command = Some(a.to_string());
        }
        i += 1;
    }
    (config, command)
}

/// Finds `--config FILE` (or `PATHFARM_CONFIG`) and the command in the raw arguments, and exports
/// the file's settings for that command as environment variables that are not set already. Runs
/// first thing in `main`, while the process has one thread.
pub fn apply(args: &[String]) -> Result<()> {
    let (flag, command) = scan(args.get(1..).unwrap_or_default());
    let path = flag.or_else(|| std::env::var_os("PATHFARM_CONFIG").map(std::path::PathBuf::from));
    let Some(path) = path else { return Ok(()) };
    let text = std::fs::read_to_string(&path)
        .with_context(|| format!("cannot read the configuration file {}", path.display()))?;
    for (var, value) in settings(&text, &path, command.as_deref().unwrap_or(""))? {
        if std::env::var_os(var).is_none() {
            std::env::set_var(var, value);
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const FILE: &str = r#"
[serve]
listen = "0.0.0.0:9000"
db = "postgres://farm@db/farm"
client-tokens = ["a", "b"]
lease-seconds = 12.5

[up]
workers = 3

[worker]
server = "http://farm:9000"
threads = 8

[client]
server = "http://farm:9000"
"#;

    fn vars(command: &str) -> Vec<(&'static str, String)> {
        settings(FILE, Path::new("farm.toml"), command).unwrap()
    }

    #[test]
    fn each_command_reads_its_tables() {
        let serve = vars("serve");
        assert!(serve.contains(&("PATHFARM_LISTEN", "0.0.0.0:9000".into())));
        assert!(serve.contains(&("PATHFARM_CLIENT_TOKENS", "a,b".into())));
        assert!(serve.contains(&("PATHFARM_LEASE_SECONDS", "12.5".into())));
        assert!(!serve.iter().any(|(v, _)| *v == "PATHFARM_WORKERS"));
        let up = vars("up");
        assert!(up.contains(&("PATHFARM_WORKERS", "3".into())));
        assert!(up.contains(&("PATHFARM_DB", "postgres://farm@db/farm".into())));
        assert!(!up.iter().any(|(v, _)| *v == "PATHFARM_LISTEN"), "{up:?}");
        assert_eq!(
            vars("worker"),
            vec![
                ("PATHFARM_SERVER", "http://farm:9000".to_string()),
                ("PATHFARM_THREADS", "8".to_string())
            ]
        );
        assert_eq!(
            vars("jobs"),
            vec![("PATHFARM_SERVER", "http://farm:9000".to_string())]
        );
        assert!(vars("render").is_empty());
    }

    #[test]
    fn tls_files_are_read_by_serve_and_the_ca_by_workers_and_clients_but_not_by_up() {
        let file = "[serve]\ntls-cert = \"c.pem\"\ntls-key = \"k.pem\"\n\
                    [worker]\nca-cert = \"ca.pem\"\n[client]\nca-cert = \"ca.pem\"\n";
        let vars = |command| settings(file, Path::new("farm.toml"), command).unwrap();
        assert_eq!(
            vars("serve"),
            vec![
                ("PATHFARM_TLS_CERT", "c.pem".to_string()),
                ("PATHFARM_TLS_KEY", "k.pem".to_string())
            ]
        );
        assert!(vars("up").is_empty());
        assert_eq!(
            vars("worker"),
            vec![("PATHFARM_CA_CERT", "ca.pem".to_string())]
        );
        assert_eq!(
            vars("submit"),
            vec![("PATHFARM_CA_CERT", "ca.pem".to_string())]
        );
    }

    fn scanned(line: &str) -> (Option<String>, Option<String>) {
        let args: Vec<String> = line.split_whitespace().map(str::to_string).collect();
        let (config, command) = scan(&args);
        (config.map(|p| p.to_string_lossy().into_owned()), command)
    }

    #[test]
    fn the_command_is_found_past_the_values_of_global_options() {
        let both = |c: &str, cmd: &str| (Some(c.to_string()), Some(cmd.to_string()));
        assert_eq!(
            scanned("--log-format json serve --config farm.toml"),
            both("farm.toml", "serve")
        );
        assert_eq!(
            scanned("--log debug --log-format=json worker --config=w.toml"),
            both("w.toml", "worker")
        );
        assert_eq!(
            scanned("--log=pathfarm=debug --config farm.toml up --workers 2"),
            both("farm.toml", "up")
        );
        // A global option's value that happens to be a command's name is still its value.
        assert_eq!(
            scanned("--config serve submit scene.glb --wait"),
            both("serve", "submit")
        );
        // After the command, an argument that names another command is only an argument.
        assert_eq!(scanned("job serve --config c.toml"), both("c.toml", "job"));
        assert_eq!(scanned("--log-format json"), (None, None));
        assert_eq!(
            scanned("render scene.glb -- --config x"),
            (None, Some("render".into()))
        );
        assert_eq!(scanned(""), (None, None));
    }

    #[test]
    fn mistakes_name_the_file_table_and_key() {
        let err = |text: &str| {
            format!(
                "{:#}",
                settings(text, Path::new("farm.toml"), "serve").unwrap_err()
            )
        };
        let e = err("[serve]\nlisten-address = \"x\"\n");
        assert!(
            e.contains("farm.toml") && e.contains("`listen-address`") && e.contains("[serve]"),
            "{e}"
        );
        assert!(e.contains("listen, db"), "{e}");
        let e = err("[server]\ndb = \"x\"\n");
        assert!(e.contains("unknown table [server]"), "{e}");
        let e = err("db = \"x\"\n");
        assert!(e.contains("`db` must be a table"), "{e}");
        let e = err("[serve\n");
        assert!(e.contains("not valid TOML"), "{e}");
        let e = err("[serve]\nclient-tokens = [\"a,b\"]\n");
        assert!(
            e.contains("[serve] client-tokens") && e.contains("commas"),
            "{e}"
        );
        // A typo in a table the command does not read is still an error.
        let e = err("[worker]\nthread = 4\n");
        assert!(e.contains("`thread`"), "{e}");
    }
}
