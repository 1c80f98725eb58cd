//! The merge of flags, file and defaults (the environment's place between flags and file is tested
//! with real processes in `tests/cli.rs`, which can set a child's environment safely).

use super::*;
use crate::Cli;
use clap::{CommandFactory, FromArgMatches};

/// A file in a directory of its own, removed when dropped.
struct TempFile(PathBuf);

impl TempFile {
    fn new(name: &str, text: &str) -> TempFile {
        static N: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
        let n = N.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
        let dir = std::env::temp_dir().join(format!("pathfarm-config-{}-{n}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(name);
        std::fs::write(&path, text).unwrap();
        TempFile(path)
    }
}

impl Drop for TempFile {
    fn drop(&mut self) {
        if let Some(dir) = self.0.parent() {
            let _ = std::fs::remove_dir_all(dir);
        }
    }
}

/// `pathfarm ARGS… --config FILE` parsed (no PATHFARM_* variable is set by any test), and the
/// merged settings of the command.
fn merged<T>(
    file: &TempFile,
    args: &[&str],
    pick: impl Fn(&Layers, crate::Command) -> Result<T>,
) -> Result<T> {
    let mut argv = vec!["pathfarm"];
    argv.extend(args);
    let path = file.0.to_string_lossy().into_owned();
    argv.extend(["--config", &path]);
    let matches = Cli::command().try_get_matches_from(argv)?;
    let cli = Cli::from_arg_matches(&matches)?;
    let sub = matches.subcommand().map_or(&matches, |(_, m)| m);
    let layers = Layers::load(cli.config.as_deref(), sub)?;
    pick(&layers, cli.command)
}

fn serve(file: &TempFile, args: &[&str]) -> Result<ServeArgs> {
    let mut all = vec!["serve"];
    all.extend(args);
    merged(file, &all, |l, c| match c {
        crate::Command::Serve(a) => l.serve(a),
        _ => unreachable!(),
    })
}

fn up(file: &TempFile, args: &[&str]) -> Result<UpArgs> {
    let mut all = vec!["up"];
    all.extend(args);
    merged(file, &all, |l, c| match c {
        crate::Command::Up(a) => l.up(a),
        _ => unreachable!(),
    })
}

const FILE: &str = r#"
[serve]
listen = "0.0.0.0:9000"
db = "postgres://farm:hunter2@db/farm"
client-tokens = ["c-1", "c,2"]
worker-tokens = ["w-1"]
lease-seconds = 12.5
max-connections = 7

[up]
workers = 3
port = 9100

[worker]
server = "http://farm:9000"
threads = 8

[client]
server = "http://farm:9000"
"#;

#[test]
fn a_flag_wins_over_the_file_which_wins_over_the_default() {
    let f = TempFile::new("farm.toml", FILE);
    let s = serve(&f, &["--lease-seconds", "40"]).unwrap();
    assert_eq!(s.server.lease_seconds, 40.0, "the flag");
    assert_eq!(s.listen.to_string(), "0.0.0.0:9000", "the file");
    assert_eq!(s.server.max_connections.get(), 7, "the file");
    assert_eq!(s.server.max_scene_mib, 256, "the default");
    assert_eq!(s.server.db.expose(), "postgres://farm:hunter2@db/farm");
    // A list is a TOML array: its items may hold commas.
    let tokens: Vec<&str> = s.server.client_tokens.iter().map(|t| t.expose()).collect();
    assert_eq!(tokens, ["c-1", "c,2"]);
    let s = serve(&f, &["--client-token", "flag-1,flag-2"]).unwrap();
    let tokens: Vec<&str> = s.server.client_tokens.iter().map(|t| t.expose()).collect();
    assert_eq!(tokens, ["flag-1", "flag-2"]);
    assert_eq!(s.server.worker_tokens.len(), 1);

    // `up` reads [up] and [serve], but not [serve]'s `listen`.
    let u = up(&f, &["--workers", "3"]).unwrap();
    assert_eq!((u.workers, u.port), (3, 9100));
    assert_eq!(
        u.threads_per_worker, None,
        "the cores shared among the workers"
    );
    assert_eq!(u.host.to_string(), "127.0.0.1");
    assert_eq!(u.server.lease_seconds, 12.5);
}

#[test]
fn a_bad_value_names_the_file_and_the_key() {
    let f = TempFile::new("pathfarm.toml", "[serve]\nlease-seconds = \"x\"\n");
    let e = format!("{:#}", serve(&f, &[]).unwrap_err());
    assert!(
        e.contains("pathfarm.toml: key \"serve.lease-seconds\": invalid type: found string \"x\""),
        "{e}"
    );
    let f = TempFile::new("farm.toml", "[up]\nport = 70000\n");
    let e = format!("{:#}", up(&f, &[]).unwrap_err());
    assert!(
        e.contains("farm.toml: key \"up.port\"") && e.contains("70000"),
        "{e}"
    );
    let f = TempFile::new("farm.toml", "[serve]\nscene-checks = 0\n");
    let e = format!("{:#}", serve(&f, &[]).unwrap_err());
    assert!(
        e.contains("key \"serve.scene-checks\"") && e.contains("nonzero"),
        "{e}"
    );
    let f = TempFile::new("farm.toml", "[serve]\nclient-tokens = \"a,b\"\n");
    let e = format!("{:#}", serve(&f, &[]).unwrap_err());
    assert!(
        e.contains("key \"serve.client-tokens\"") && e.contains("sequence"),
        "{e}"
    );
    // A bad value in a table the command does not merge is found when that command runs; a flag
    // that replaces it hides it.
    let f = TempFile::new("farm.toml", "[serve]\nlease-seconds = \"x\"\n");
    assert!(serve(&f, &["--lease-seconds", "5"]).is_ok());
}

#[test]
fn mistakes_in_the_file_name_the_file_table_and_key() {
    let err = |text: &str| {
        let f = TempFile::new("farm.toml", text);
        format!("{:#}", serve(&f, &[]).unwrap_err())
    };
    let e = err("[serve]\nlisten-address = \"x\"\n");
    assert!(
        e.contains("farm.toml") && e.contains("`listen-address`") && e.contains("[serve]"),
        "{e}"
    );
    assert!(e.contains("listen") && e.contains("db"), "{e}");
    let e = err("[server]\ndb = \"x\"\n");
    assert!(e.contains("unknown table [server]"), "{e}");
    let e = err("db = \"x\"\n");
    assert!(e.contains("`db` must be a table"), "{e}");
    let e = err("[serve\n");
    assert!(e.contains("farm.toml"), "{e}");
    // A typo in a table the command does not read is still an error.
    let e = err("[worker]\nthread = 4\n");
    assert!(e.contains("`thread`"), "{e}");
    // `up` has no `listen` of its own, nor does any table know `token-stdin`.
    let e = err("[up]\nlisten = \"127.0.0.1:1\"\n");
    assert!(e.contains("`listen`"), "{e}");
    let e = err("[worker]\ntoken-stdin = true\n");
    assert!(e.contains("`token-stdin`"), "{e}");
    // A file that is not there is an error, not an empty file.
    let f = TempFile::new("farm.toml", "");
    let missing = f.0.with_file_name("missing.toml");
    let matches = Cli::command().get_matches_from(["pathfarm", "jobs"]);
    let e = Layers::load(Some(&missing), &matches).err().unwrap();
    assert!(format!("{e:#}").contains("missing.toml"), "{e:#}");
}

#[test]
fn the_tables_keys_are_the_documented_ones() {
    assert_eq!(
        keys("up"),
        ["workers", "threads-per-worker", "lanes", "port", "host"]
    );
    let serve = keys("serve");
    for k in [
        "listen",
        "tls-cert",
        "tls-key",
        "tls-reload-seconds",
        "db",
        "client-tokens",
        "worker-tokens",
        "lease-seconds",
        "worker-expiry-seconds",
    ] {
        assert!(serve.contains(&k.to_string()), "{k}: {serve:?}");
    }
    assert_eq!(keys("client"), ["server", "token", "ca-cert"]);
    let worker = keys("worker");
    assert!(worker.contains(&"token".to_string()) && !worker.contains(&"token-stdin".to_string()));
    // Every key of the README's table, and no other.
    let readme = include_str!("../../../../README.md");
    for table in TABLES {
        for key in keys(table) {
            assert!(
                readme.contains(&format!("`{key}`")),
                "[{table}] {key} is not in the README"
            );
        }
    }
}

#[test]
fn secrets_are_redacted_in_debug() {
    let f = TempFile::new("farm.toml", FILE);
    let s = serve(&f, &[]).unwrap();
    let text = format!("{s:?}");
    for secret in ["hunter2", "c-1", "w-1"] {
        assert!(!text.contains(secret), "{secret} in {text}");
    }
    assert!(text.contains("\"***\""), "{text}");
}
