//! The deployment files of `docker/` held to the repository and to the binary, on a machine with
//! no container engine (see docker/README.md, "How these were checked"):
//! - the Dockerfile copies only sources that exist and that its `.dockerignore` lets through, its
//!   dependency stage copies every workspace member's manifest, and that stage's stand-in tree,
//!   made by running its own `RUN` line, is a workspace `cargo metadata --locked` accepts with
//!   every target file present; its Rust image is the version `rust-toolchain.toml` pins;
//! - every `pathfarm` subcommand, flag and `PATHFARM_*` variable the compose file, the Kubernetes
//!   objects, the systemd units and their env files pass exists in the binary (`--help`);
//! - no file carries a default secret: compose refuses to start without them, and `serve` refuses
//!   the empty tokens the examples leave.

use serde_norway::Value;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::Command;

const BIN: &str = env!("CARGO_BIN_EXE_pathfarm");

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn read(rel: &str) -> String {
    std::fs::read_to_string(root().join(rel)).unwrap_or_else(|e| panic!("cannot read {rel}: {e}"))
}

/// One Dockerfile instruction: continuation lines joined, comments dropped.
#[derive(Debug)]
struct Instruction {
    line: usize,
    keyword: String,
    args: String,
}

fn dockerfile() -> Vec<Instruction> {
    let text = read("docker/Dockerfile");
    let mut out = Vec::new();
    let mut current: Option<(usize, String)> = None;
    for (i, raw) in text.lines().enumerate() {
        let trimmed = raw.trim();
        if trimmed.starts_with('#') || (trimmed.is_empty() && current.is_none()) {
            continue;
        }
        let (line, mut body) = current.take().unwrap_or((i + 1, String::new()));
        let continued = trimmed.ends_with('\\');
        body.push_str(trimmed.trim_end_matches('\\'));
        body.push(' ');
        if continued {
            current = Some((line, body));
        } else {
            let body = body.trim().to_string();
            let (keyword, args) = body.split_once(char::is_whitespace).unwrap_or((&body, ""));
            out.push(Instruction {
                line,
                keyword: keyword.to_ascii_uppercase(),
                args: args.trim().to_string(),
            });
        }
    }
    assert!(current.is_none(), "the Dockerfile ends in a continued line");
    out
}

/// A COPY's sources and destination (no `--from`), or None for a copy between stages.
fn copy_parts(ins: &Instruction) -> Option<(Vec<String>, String)> {
    let words: Vec<&str> = ins.args.split_whitespace().collect();
    if words.iter().any(|w| w.starts_with("--from")) {
        return None;
    }
    let words: Vec<&str> = words.into_iter().filter(|w| !w.starts_with("--")).collect();
    let (dest, sources) = words.split_last().expect("COPY has a destination");
    assert!(
        !sources.is_empty(),
        "Dockerfile line {}: COPY without sources",
        ins.line
    );
    Some((
        sources.iter().map(|s| s.to_string()).collect(),
        dest.to_string(),
    ))
}

/// The builder stage's instructions before its first `cargo build`: the dependency stage.
fn dependency_stage(all: &[Instruction]) -> &[Instruction] {
    let end = all
        .iter()
        .position(|i| i.keyword == "RUN" && i.args.contains("cargo build"))
        .expect("the Dockerfile builds with cargo build");
    &all[..end]
}

fn workspace_members() -> Vec<String> {
    let manifest: toml::Table = read("Cargo.toml").parse().expect("parse Cargo.toml");
    manifest["workspace"]["members"]
        .as_array()
        .expect("workspace.members")
        .iter()
        .map(|m| m.as_str().expect("a member path").to_string())
        .collect()
}

/// A `.dockerignore` pattern (`*` within a component, `**` across components) against a path.
fn glob(pattern: &[&str], path: &[&str]) -> bool {
    match (pattern.split_first(), path.split_first()) {
        (None, None) => true,
        (Some((&"**", rest)), _) => {
            glob(rest, path) || path.split_first().is_some_and(|(_, p)| glob(pattern, p))
        }
        (Some((p, prest)), Some((c, crest))) => component(p, c) && glob(prest, crest),
        _ => false,
    }
}

fn component(pattern: &str, name: &str) -> bool {
    match pattern.split_once('*') {
        None => pattern == name,
        Some((head, tail)) => {
            name.len() >= head.len()
                && name.starts_with(head)
                && (0..=name.len() - head.len()).any(|k| {
                    name.is_char_boundary(head.len() + k)
                        && component(tail, &name[head.len() + k..])
                })
        }
    }
}

/// Whether the build context leaves `path` out: a pattern matches it or a folder above it.
fn ignored(patterns: &[String], path: &str) -> bool {
    let parts: Vec<&str> = path.trim_start_matches("./").split('/').collect();
    patterns.iter().any(|p| {
        let pat: Vec<&str> = p.trim_start_matches('/').split('/').collect();
        (1..=parts.len()).any(|n| glob(&pat, &parts[..n]))
    })
}

fn dockerignore() -> Vec<String> {
    read("docker/Dockerfile.dockerignore")
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
        .map(str::to_string)
        .collect()
}

#[test]
fn the_dockerignore_matcher_matches_as_buildkit_does() {
    let p = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
    assert!(ignored(&p(&["target"]), "target/release/pathfarm"));
    assert!(!ignored(&p(&["target"]), "crates/x/target"));
    assert!(ignored(&p(&["**/target"]), "crates/x/target/debug"));
    assert!(ignored(&p(&["*.png"]), "a.png"));
    assert!(!ignored(&p(&["*.png"]), "crates/a.png"));
    assert!(ignored(&p(&["pathfarm.db*"]), "pathfarm.db-wal"));
    assert!(!ignored(&p(&["tests"]), "crates/pathfarm/Cargo.toml"));
}

#[test]
fn the_dockerfile_copies_what_exists_and_every_workspace_member() {
    let all = dockerfile();
    let ignore = dockerignore();
    let mut problems = Vec::new();
    for ins in all.iter().filter(|i| i.keyword == "COPY") {
        let Some((sources, _)) = copy_parts(ins) else {
            continue;
        };
        for s in sources {
            if !root().join(&s).exists() {
                problems.push(format!(
                    "line {}: COPY {s}: no such file in the repository",
                    ins.line
                ));
            } else if ignored(&ignore, &s) {
                problems.push(format!(
                    "line {}: COPY {s}: Dockerfile.dockerignore leaves it out of the context",
                    ins.line
                ));
            }
        }
    }
    let copied: BTreeSet<String> = dependency_stage(&all)
        .iter()
        .filter(|i| i.keyword == "COPY")
        .filter_map(copy_parts)
        .flat_map(|(sources, _)| sources)
        .collect();
    for needed in ["Cargo.toml".to_string(), "Cargo.lock".to_string()]
        .into_iter()
        .chain(
            workspace_members()
                .iter()
                .map(|m| format!("{m}/Cargo.toml")),
        )
    {
        if !copied.contains(&needed) {
            problems.push(format!(
                "the dependency stage does not COPY {needed} (a workspace manifest)"
            ));
        }
    }
    // The builder's Rust is the toolchain the repository pins.
    let toolchain: toml::Table = read("rust-toolchain.toml")
        .parse()
        .expect("parse rust-toolchain.toml");
    let channel = toolchain["toolchain"]["channel"]
        .as_str()
        .expect("toolchain.channel");
    let from = all
        .iter()
        .find(|i| i.keyword == "FROM")
        .expect("a FROM line");
    if !from.args.starts_with(&format!("rust:{channel}-")) {
        problems.push(format!(
            "line {}: FROM {} is not rust:{channel}-… (rust-toolchain.toml)",
            from.line, from.args
        ));
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// Copies the directory `from`'s files and folders into `to`, as a Dockerfile's `COPY` of a
/// directory does.
fn copy_tree(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).expect("create a COPY destination");
    for entry in std::fs::read_dir(from).expect("read a COPY source") {
        let entry = entry.expect("a directory entry");
        let path = entry.path();
        if path.is_dir() {
            copy_tree(&path, &to.join(entry.file_name()));
        } else {
            std::fs::copy(&path, to.join(entry.file_name())).expect("copy");
        }
    }
}

/// The dependency stage, replayed in a scratch directory: its COPYs, then its `RUN` lines but the
/// build (the stand-ins), then `cargo metadata --locked --offline`, which loads the workspace as
/// `cargo build -p pathfarm` does. Every member must be there, every target file of every member
/// present, and the lock file unchanged.
#[test]
fn the_dependency_stage_is_a_workspace_cargo_accepts() {
    let all = dockerfile();
    let scratch = std::env::temp_dir().join(format!("pathfarm-docker-deps-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&scratch);
    std::fs::create_dir_all(&scratch).expect("create the scratch directory");
    for ins in dependency_stage(&all) {
        match ins.keyword.as_str() {
            "COPY" => {
                let (sources, dest) = copy_parts(ins).expect("no --from in the dependency stage");
                for s in sources {
                    let from = root().join(&s);
                    if from.is_dir() {
                        // `COPY DIR DEST`: DIR's contents into DEST.
                        copy_tree(&from, &scratch.join(dest.trim_start_matches("./")));
                        continue;
                    }
                    assert!(from.is_file(), "line {}: {s} is not a file", ins.line);
                    let to_dir = scratch.join(dest.trim_start_matches("./"));
                    std::fs::create_dir_all(&to_dir).expect("create the COPY destination");
                    let name = Path::new(&s).file_name().expect("a file name");
                    std::fs::copy(&from, to_dir.join(name)).expect("copy");
                }
            }
            "RUN" => {
                let out = Command::new("sh")
                    .arg("-ec")
                    .arg(&ins.args)
                    .current_dir(&scratch)
                    .output()
                    .expect("run sh");
                assert!(
                    out.status.success(),
                    "line {}: RUN failed: {}",
                    ins.line,
                    String::from_utf8_lossy(&out.stderr)
                );
            }
            _ => {}
        }
    }
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    // This platform's dependencies only: the others' sources were never downloaded (offline).
    let version = Command::new(&cargo)
        .arg("-vV")
        .output()
        .expect("run cargo -vV");
    let version = String::from_utf8_lossy(&version.stdout);
    let host = version
        .lines()
        .find_map(|l| l.strip_prefix("host: "))
        .expect("cargo -vV names the host");
    let out = Command::new(&cargo)
        .args(["metadata", "--locked", "--offline", "--format-version", "1"])
        .args(["--filter-platform", host])
        .current_dir(&scratch)
        .env("CARGO_TARGET_DIR", scratch.join("target"))
        .output()
        .expect("run cargo metadata");
    assert!(
        out.status.success(),
        "cargo metadata refuses the dependency stage's tree: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let meta: serde_json::Value = serde_json::from_slice(&out.stdout).expect("metadata JSON");
    let members = meta["workspace_members"]
        .as_array()
        .expect("workspace_members");
    assert_eq!(members.len(), workspace_members().len(), "{members:?}");
    let mut missing = Vec::new();
    for package in meta["packages"].as_array().expect("packages") {
        if package["source"].is_string() {
            continue; // crates.io
        }
        for target in package["targets"].as_array().expect("targets") {
            let src = target["src_path"].as_str().expect("src_path");
            if !Path::new(src).exists() {
                missing.push(src.to_string());
            }
        }
    }
    assert!(
        missing.is_empty(),
        "target files without a stand-in: {missing:?}"
    );
    let lock = std::fs::read(scratch.join("Cargo.lock")).expect("read the copied lock file");
    assert!(
        lock == std::fs::read(root().join("Cargo.lock")).expect("read Cargo.lock"),
        "cargo changed Cargo.lock in the dependency stage"
    );
    let _ = std::fs::remove_dir_all(&scratch);
}

/// What `pathfarm SUB --help` lists: its long options and the variables they read.
#[derive(Default)]
struct Accepted {
    flags: BTreeSet<String>,
    env: BTreeSet<String>,
}

fn accepted(sub: &str, cache: &mut BTreeMap<String, Accepted>) -> bool {
    if cache.contains_key(sub) {
        return true;
    }
    let out = Command::new(BIN)
        .args([sub, "--help"])
        .env_remove("PATHFARM_CONFIG")
        .output()
        .expect("run pathfarm --help");
    if !out.status.success() {
        return false;
    }
    let help = String::from_utf8_lossy(&out.stdout);
    let mut a = Accepted::default();
    for line in help.lines() {
        let t = line.trim_start();
        if t.starts_with('-') {
            for word in t.split([' ', ',', '=', '<', '[']) {
                if word.starts_with("--") && word.len() > 2 {
                    a.flags.insert(word.to_string());
                }
            }
        }
        let mut rest = line;
        while let Some(i) = rest.find("[env: ") {
            rest = &rest[i + 6..];
            let name: String = rest
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                .collect();
            a.env.insert(name);
        }
    }
    assert!(
        a.flags.contains("--help"),
        "no options read from `pathfarm {sub} --help`:\n{help}"
    );
    cache.insert(sub.to_string(), a);
    true
}

/// Checks `pathfarm ARGS…` (a subcommand, then options and their values) and the variables given
/// to it; pushes what the binary does not know to `problems`.
fn check_invocation(
    what: &str,
    args: &[String],
    env: &[String],
    cache: &mut BTreeMap<String, Accepted>,
    problems: &mut Vec<String>,
) {
    let Some(sub) = args.first() else {
        problems.push(format!("{what}: no subcommand"));
        return;
    };
    if !accepted(sub, cache) {
        problems.push(format!("{what}: `pathfarm {sub}` is not a subcommand"));
        return;
    }
    let a = &cache[sub.as_str()];
    for arg in &args[1..] {
        if arg.starts_with("--") {
            let flag = arg.split('=').next().unwrap_or(arg);
            if !a.flags.contains(flag) {
                problems.push(format!("{what}: `pathfarm {sub}` has no option {flag}"));
            }
        }
    }
    for var in env {
        if !a.env.contains(var) {
            problems.push(format!("{what}: `pathfarm {sub}` reads no variable {var}"));
        }
    }
}

fn strings(v: &Value) -> Vec<String> {
    v.as_sequence()
        .map(|s| {
            s.iter()
                .map(|x| match x {
                    Value::String(s) => s.clone(),
                    other => serde_norway::to_string(other)
                        .unwrap_or_default()
                        .trim()
                        .to_string(),
                })
                .collect()
        })
        .unwrap_or_default()
}

/// The `CMD` of the image (its default arguments), from the Dockerfile's exec form.
fn image_cmd(all: &[Instruction]) -> Vec<String> {
    let cmd = all
        .iter()
        .rev()
        .find(|i| i.keyword == "CMD")
        .expect("a CMD line");
    serde_json::from_str(&cmd.args).expect("CMD in exec (JSON) form")
}

#[test]
fn compose_kubernetes_and_systemd_pass_only_what_the_binary_accepts() {
    let mut cache = BTreeMap::new();
    let mut problems = Vec::new();
    let all = dockerfile();
    let default_cmd = image_cmd(&all);

    // The image's own defaults: ENV PATHFARM_*=… for its CMD.
    let image_env: Vec<String> = all
        .iter()
        .filter(|i| i.keyword == "ENV")
        .flat_map(|i| {
            i.args
                .split_whitespace()
                .filter_map(|kv| kv.split_once('=').map(|(k, _)| k.to_string()))
                .collect::<Vec<_>>()
        })
        .filter(|k| k.starts_with("PATHFARM_"))
        .collect();
    check_invocation(
        "Dockerfile CMD/ENV",
        &default_cmd,
        &image_env,
        &mut cache,
        &mut problems,
    );

    // compose.yaml: every service that runs the pathfarm image.
    let mut compose: Value =
        serde_norway::from_str(&read("docker/compose.yaml")).expect("parse compose.yaml");
    compose
        .apply_merge()
        .expect("resolve compose.yaml's merge keys");
    let services = compose["services"].as_mapping().expect("services");
    let mut pathfarm_services = 0;
    for (name, service) in services {
        let name = name.as_str().unwrap_or("?");
        let image = service["image"].as_str().unwrap_or("");
        if !image.starts_with("pathfarm") {
            continue;
        }
        pathfarm_services += 1;
        let command = match service.get("command") {
            Some(c) => strings(c),
            None => default_cmd.clone(),
        };
        let env: Vec<String> = match service.get("environment") {
            Some(Value::Mapping(m)) => m
                .keys()
                .filter_map(|k| k.as_str().map(str::to_string))
                .collect(),
            Some(Value::Sequence(s)) => s
                .iter()
                .filter_map(|kv| kv.as_str()?.split('=').next().map(str::to_string))
                .collect(),
            _ => Vec::new(),
        };
        check_invocation(
            &format!("compose.yaml service {name}"),
            &command,
            &env,
            &mut cache,
            &mut problems,
        );
    }
    assert!(
        pathfarm_services >= 3,
        "compose.yaml: only {pathfarm_services} pathfarm services found"
    );

    // k8s/: the containers of every Deployment; the Secret keys they read exist.
    let mut secret_keys = BTreeSet::new();
    let mut containers = Vec::new();
    let mut k8s_files: Vec<PathBuf> = std::fs::read_dir(root().join("docker/k8s"))
        .expect("read docker/k8s")
        .map(|e| e.expect("a directory entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "yaml"))
        .collect();
    k8s_files.sort();
    for path in &k8s_files {
        let text = std::fs::read_to_string(path).expect("read a k8s file");
        let file = path.file_name().map(|n| n.to_string_lossy().into_owned());
        let file = file.unwrap_or_default();
        for doc in text.split("\n---\n") {
            let doc: Value =
                serde_norway::from_str(doc).unwrap_or_else(|e| panic!("{file}: not YAML: {e}"));
            match doc["kind"].as_str() {
                Some("Secret") => {
                    for section in ["stringData", "data"] {
                        if let Some(m) = doc[section].as_mapping() {
                            secret_keys
                                .extend(m.keys().filter_map(|k| k.as_str()).map(String::from));
                        }
                    }
                }
                Some("Deployment") => {
                    for c in doc["spec"]["template"]["spec"]["containers"]
                        .as_sequence()
                        .expect("containers")
                    {
                        containers.push((file.clone(), c.clone()));
                    }
                }
                _ => {}
            }
        }
    }
    assert!(
        containers.len() >= 2,
        "k8s/: {} containers",
        containers.len()
    );
    for (file, c) in &containers {
        let name = c["name"].as_str().unwrap_or("?");
        let what = format!("k8s/{file} container {name}");
        let args = match c.get("args") {
            Some(a) => strings(a),
            None => default_cmd.clone(),
        };
        let mut env = Vec::new();
        for e in c["env"].as_sequence().map(Vec::as_slice).unwrap_or(&[]) {
            env.push(e["name"].as_str().unwrap_or("?").to_string());
            if let Some(key) = e["valueFrom"]["secretKeyRef"]["key"].as_str() {
                if !secret_keys.contains(key) {
                    problems.push(format!(
                        "{what}: Secret key {key} is not in the example Secret"
                    ));
                }
            }
        }
        check_invocation(&what, &args, &env, &mut cache, &mut problems);
    }

    // systemd: ExecStart's subcommand and flags; the env file's variables, and the flags in the
    // *_ARGS variables ExecStart expands (commented-out examples included).
    for (unit, env_file) in [
        ("pathfarm-serve.service", "serve.env.example"),
        ("pathfarm-worker@.service", "worker.env.example"),
    ] {
        let text = read(&format!("docker/systemd/{unit}"));
        let exec = text
            .lines()
            .find_map(|l| l.strip_prefix("ExecStart="))
            .unwrap_or_else(|| panic!("{unit}: no ExecStart"));
        let words: Vec<String> = exec.split_whitespace().map(String::from).collect();
        assert!(
            words.first().is_some_and(|w| w.ends_with("/pathfarm")),
            "{unit}: ExecStart does not run pathfarm: {exec}"
        );
        let expanded: BTreeSet<String> = words
            .iter()
            .filter_map(|w| w.strip_prefix('$'))
            .map(|w| w.trim_matches(['{', '}']).to_string())
            .collect();
        let args: Vec<String> = words[1..]
            .iter()
            .filter(|w| !w.starts_with('$'))
            .cloned()
            .collect();
        let mut env = Vec::new();
        let mut extra_args = Vec::new();
        for line in read(&format!("docker/systemd/{env_file}")).lines() {
            let l = line.trim().trim_start_matches('#');
            let Some((k, v)) = l.split_once('=') else {
                continue;
            };
            if k.is_empty() || !k.chars().all(|c| c.is_ascii_uppercase() || c == '_') {
                continue;
            }
            if expanded.contains(k) {
                extra_args.extend(v.split_whitespace().map(String::from));
            } else if k.starts_with("PATHFARM_") {
                env.push(k.to_string());
            }
        }
        let mut all_args = args.clone();
        all_args.extend(extra_args);
        check_invocation(
            &format!("systemd/{unit} with {env_file}"),
            &all_args,
            &env,
            &mut cache,
            &mut problems,
        );
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));

    // The checker itself: a flag or variable the binary lacks is caught.
    let mut caught = Vec::new();
    check_invocation(
        "self-check",
        &["serve".into(), "--no-such-flag".into()],
        &["PATHFARM_NO_SUCH".into()],
        &mut cache,
        &mut caught,
    );
    assert_eq!(caught.len(), 2, "{caught:?}");
}

/// No deployment file carries a usable default secret: compose stops with a message when one is
/// missing, and the examples leave tokens empty, which `serve` refuses off loopback.
#[test]
fn no_default_secrets_and_serve_refuses_to_start_without_tokens() {
    let mut problems = Vec::new();
    let mut stack = vec![root().join("docker")];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).expect("read a docker/ folder") {
            let path = entry.expect("an entry").path();
            if path.is_dir() {
                stack.push(path);
                continue;
            }
            let text = std::fs::read_to_string(&path).unwrap_or_default();
            for (i, line) in text.lines().enumerate() {
                let lower = line.to_ascii_lowercase();
                if lower.contains("change-me") || lower.contains("changeme") {
                    problems.push(format!("{}:{}: {line}", path.display(), i + 1));
                }
            }
        }
    }
    let compose = read("docker/compose.yaml");
    for var in [
        "POSTGRES_PASSWORD",
        "PATHFARM_CLIENT_TOKEN",
        "PATHFARM_WORKER_TOKEN",
    ] {
        let mut rest = compose.as_str();
        let mut uses = 0;
        while let Some(i) = rest.find(&format!("${{{var}")) {
            rest = &rest[i + var.len() + 2..];
            uses += 1;
            if !rest.starts_with(":?") {
                problems.push(format!(
                    "compose.yaml: ${{{var}…}} must be required (${{{var}:?…}}), not defaulted"
                ));
            }
        }
        if uses == 0 {
            problems.push(format!("compose.yaml never reads {var}"));
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));

    // What the examples leave empty is refused: serve on 0.0.0.0 with empty token lists.
    let out = Command::new(BIN)
        .args(["serve", "--listen", "0.0.0.0:0", "--db", "unused.db"])
        .env("PATHFARM_CLIENT_TOKENS", "")
        .env("PATHFARM_WORKER_TOKENS", "")
        .env_remove("PATHFARM_CONFIG")
        .current_dir(std::env::temp_dir())
        .output()
        .expect("run pathfarm serve");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && stderr.contains("without tokens"),
        "serve started without tokens: {stderr}"
    );
}
