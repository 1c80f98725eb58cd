//! The schema migrations, embedded in the binary: `migrations/{sqlite,postgres}/NNNN_name.sql`.
//!
//! They are listed here with `include_str!` rather than found by sqlx's `migrate!` macro, which
//! needs sqlx's compile-time machinery: a second build of SQLite and of both database drivers, for
//! the proc-macro, about a minute of every clean build on two cores. The migrations are the ones
//! the macro would make, checksums included, so a database migrated by either accepts the other
//! (`the_embedded_migrations_are_the_directorys` checks this against sqlx's own reading of the
//! directory, and that no file is left out).

use sqlx::migrate::{Migration, MigrationType, Migrator};
use sqlx::SqlSafeStr;
use std::borrow::Cow;
use std::sync::LazyLock;

/// One migration file: its name (`<version>_<description>.sql`) and contents.
type File = (&'static str, &'static str);

macro_rules! migration_files {
    ($dialect:literal: $($name:literal),+ $(,)?) => {
        &[$(($name, include_str!(concat!("../../../../migrations/", $dialect, "/", $name)))),+]
    };
}

/// The SQLite schema's migrator.
pub(super) static SQLITE: LazyLock<Migrator> = LazyLock::new(|| {
    migrator(migration_files!(
        "sqlite": "0001_init.sql",
        "0002_convergence.sql",
        "0003_environment_and_warnings.sql",
        "0004_worker_identity.sql",
        "0005_frames.sql",
        "0006_retention_and_quotas.sql",
        "0007_all_invalid_slices.sql",
        "0008_frame_versions.sql",
        "0009_verification.sql",
        "0010_tile_error_sums.sql",
        "0011_worker_list_order.sql",
    ))
});

/// The PostgreSQL schema's migrator.
pub(super) static POSTGRES: LazyLock<Migrator> = LazyLock::new(|| {
    migrator(migration_files!(
        "postgres": "0001_init.sql",
        "0002_convergence.sql",
        "0003_environment_and_warnings.sql",
        "0004_worker_identity.sql",
        "0005_frames.sql",
        "0006_retention_and_quotas.sql",
        "0007_all_invalid_slices.sql",
        "0008_frame_versions.sql",
        "0009_verification.sql",
        "0010_tile_error_sums.sql",
        "0011_worker_list_order.sql",
        "0012_lease_and_merge_functions.sql",
        "0013_lease_reads_its_candidates.sql",
    ))
});

fn migrator(files: &'static [File]) -> Migrator {
    Migrator::with_migrations(
        files
            .iter()
            .map(|&(name, sql)| migration(name, sql))
            .collect(),
    )
}

/// A migration as sqlx reads one from a directory: version and description from the file name
/// (underscores in the description become spaces), `-- no-transaction` as the first line to run it
/// outside a transaction, the checksum of the whole file.
fn migration(name: &'static str, sql: &'static str) -> Migration {
    // The names are the constants above, checked by the tests: a bad one is a build defect.
    let (version, rest) = name
        .split_once('_')
        .unwrap_or_else(|| panic!("migration file {name:?} is not <version>_<description>.sql"));
    let version: i64 = version
        .parse()
        .unwrap_or_else(|_| panic!("migration file {name:?} has no integer version"));
    let migration_type = MigrationType::from_filename(rest);
    let description = rest
        .trim_end_matches(migration_type.suffix())
        .replace('_', " ");
    Migration::new(
        version,
        Cow::Owned(description),
        migration_type,
        sql.into_sql_str(),
        sql.starts_with("-- no-transaction"),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    /// The fields by which sqlx tells migrations apart, and checks applied ones against.
    fn fields(m: &Migrator) -> Vec<(i64, String, String, Vec<u8>, bool)> {
        m.iter()
            .map(|m| {
                (
                    m.version,
                    m.description.to_string(),
                    format!("{:?}", m.migration_type),
                    m.checksum.to_vec(),
                    m.no_tx,
                )
            })
            .collect()
    }

    #[tokio::test]
    async fn the_embedded_migrations_are_the_directorys() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../migrations");
        for (dialect, embedded) in [("sqlite", &*SQLITE), ("postgres", &*POSTGRES)] {
            let dir = root.join(dialect);
            let read = Migrator::new(dir.as_path())
                .await
                .unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
            assert!(read.iter().count() >= 2, "{dialect}: no migrations read");
            assert_eq!(
                fields(embedded),
                fields(&read),
                "{dialect}: the embedded list differs from {} (a file added there must be \
                 listed in store/migrations.rs)",
                dir.display()
            );
        }
    }
}
