//! Settings from flags, environment variables and the optional TOML file (`--config FILE` or
//! `PATHFARM_CONFIG`), merged by figment.
//!
//! clap reads the flags and the environment (each option's `env` names its variable; a flag wins
//! over its variable) and knows the defaults; `--help` lists all three. It also tells where each
//! value came from (`ArgMatches::value_source`). [`Layers::merge`] then stacks, for one settings
//! struct and one table of the file: clap's defaults, under the file's `[table]`, under what clap
//! found on the command line or in the environment, and extracts the typed struct with figment. So
//! the precedence is flag > environment > file > default, and a bad value in the file is an error
//! that names the file and the key. Nothing is written into the process's environment: children
//! (`up`'s workers) inherit nothing from the file.
//!
//! The keys of a table are the settings struct's field names in kebab case, which are the flags'
//! long names (but `client-tokens` and `worker-tokens`, lists, for `--client-token` and
//! `--worker-token`). Every table and key of the file is checked, whichever command runs.

use crate::commands::{client::ClientArgs, serve::ServeArgs, up::UpArgs, worker::WorkerArgs};
use anyhow::{bail, Context, Result};
use clap::parser::ValueSource;
use clap::{ArgMatches, Args};
use figment::providers::{Format, Serialized, Toml};
use figment::value::{Dict, Value};
use figment::Figment;
use serde::{de::DeserializeOwned, Serialize};
use std::path::{Path, PathBuf};

/// Variables that may hold a secret: never passed on to child processes.
pub const SECRET_VARIABLES: &[&str] = &[
    "PATHFARM_CLIENT_TOKENS",
    "PATHFARM_WORKER_TOKENS",
    "PATHFARM_WORKER_TOKEN",
    "PATHFARM_TOKEN",
    "PATHFARM_DB",
    "PATHFARM_CONFIG",
];

/// The tables of the file.
const TABLES: &[&str] = &["serve", "up", "worker", "client"];

/// Flags that are not settings: no key of the file.
const NOT_IN_FILE: &[&str] = &["token-stdin"];

/// The keys of `[table]`: its settings structs' options (`up` has its own four; its server's are
/// `[serve]`'s).
fn keys(table: &str) -> Vec<String> {
    let cmd = clap::Command::new("keys");
    let cmd = match table {
        "serve" => ServeArgs::augment_args(cmd),
        "up" => UpArgs::augment_args(cmd),
        "worker" => WorkerArgs::augment_args(cmd),
        "client" => ClientArgs::augment_args(cmd),
        _ => return Vec::new(),
    };
    let serve = ServeArgs::augment_args(clap::Command::new("serve"));
    cmd.get_arguments()
        .map(|a| a.get_id().as_str().replace('_', "-"))
        .filter(|k| !NOT_IN_FILE.contains(&k.as_str()))
        // `up` flattens the server's settings, which belong to `[serve]`.
        .filter(|k| {
            table != "up"
                || !serve
                    .get_arguments()
                    .any(|a| a.get_id().as_str().replace('_', "-") == *k)
        })
        .collect()
}

/// The configuration file, read and checked.
struct File {
    path: PathBuf,
    figment: Figment,
}

impl File {
    fn load(path: &Path) -> Result<File> {
        // figment takes a missing file for an empty one: a file named must exist.
        std::fs::metadata(path)
            .with_context(|| format!("cannot read the configuration file {}", path.display()))?;
        let figment = Figment::from(Toml::file_exact(path));
        let file = File {
            path: path.to_path_buf(),
            figment,
        };
        let all: Dict = file.figment.extract().map_err(|e| file.error(None, e))?;
        for (table, value) in &all {
            let Some(entries) = value.as_dict() else {
                bail!(
                    "{}: `{table}` must be a table ([serve], [up], [worker] or [client])",
                    path.display()
                );
            };
            if !TABLES.contains(&table.as_str()) {
                bail!(
                    "{}: unknown table [{table}] (expected [serve], [up], [worker] or [client])",
                    path.display()
                );
            }
            let known = keys(table);
            for key in entries.keys() {
                if !known.contains(key) {
                    bail!(
                        "{}: unknown key `{key}` in [{table}] (known: {})",
                        path.display(),
                        known.join(", ")
                    );
                }
            }
        }
        Ok(file)
    }

    /// figment's error as one line that names the file and the key: `farm.toml: key
    /// "serve.lease-seconds": invalid type: …`.
    fn error(&self, table: Option<&str>, e: figment::Error) -> anyhow::Error {
        let lines: Vec<String> = e
            .into_iter()
            .map(|e| {
                let key: Vec<&str> = table
                    .into_iter()
                    .chain(e.path.iter().map(String::as_str))
                    .collect();
                if e.path.is_empty() {
                    format!("{}: {}", self.path.display(), e.kind)
                } else {
                    format!(
                        "{}: key \"{}\": {}",
                        self.path.display(),
                        key.join("."),
                        e.kind
                    )
                }
            })
            .collect();
        anyhow::anyhow!(lines.join("; "))
    }
}

/// What the settings of the command that runs are merged from: the file (if any) and clap's
/// matches of the command.
pub struct Layers<'a> {
    file: Option<File>,
    matches: &'a ArgMatches,
}

impl<'a> Layers<'a> {
    /// `config`: the `--config` file (or `PATHFARM_CONFIG`'s); `matches`: the subcommand's.
    pub fn load(config: Option<&Path>, matches: &'a ArgMatches) -> Result<Layers<'a>> {
        Ok(Layers {
            file: config.map(File::load).transpose()?,
            matches,
        })
    }

    /// `parsed` (clap's values) with the file's `[table]` merged under the flags and environment
    /// and over the defaults. Nested settings structs (`up`'s and `serve`'s server) pass through
    /// unchanged: merge them on their own.
    pub fn merge<T: Serialize + DeserializeOwned>(&self, table: &str, parsed: T) -> Result<T> {
        let Some(file) = &self.file else {
            return Ok(parsed);
        };
        let values = Value::serialize(&parsed)
            .context("internal: settings that do not serialize")?
            .into_dict()
            .context("internal: settings that are not a struct")?;
        let (mut defaults, mut given) = (Dict::new(), Dict::new());
        for (key, value) in values {
            let explicit = !matches!(value, Value::Dict(..))
                && matches!(
                    self.matches.value_source(&key.replace('-', "_")),
                    Some(ValueSource::CommandLine | ValueSource::EnvVariable)
                );
            if explicit {
                given.insert(key, value);
            } else {
                defaults.insert(key, value);
            }
        }
        Figment::from(Serialized::defaults(defaults))
            .merge(file.figment.focus(table))
            .merge(Serialized::defaults(given))
            .extract()
            .map_err(|e| file.error(Some(table), e))
    }

    pub fn serve(&self, args: ServeArgs) -> Result<ServeArgs> {
        let mut args = self.merge("serve", args)?;
        args.server = self.merge("serve", args.server)?;
        Ok(args)
    }

    pub fn up(&self, args: UpArgs) -> Result<UpArgs> {
        let mut args = self.merge("up", args)?;
        args.server = self.merge("serve", args.server)?;
        Ok(args)
    }

    pub fn worker(&self, args: WorkerArgs) -> Result<WorkerArgs> {
        self.merge("worker", args)
    }

    pub fn client(&self, args: ClientArgs) -> Result<ClientArgs> {
        self.merge("client", args)
    }
}

#[cfg(test)]
mod tests;
