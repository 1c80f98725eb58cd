//! Several writes sent to the database as one request.
//!
//! sqlx runs each SQLite connection on a thread of its own, and every statement is a round trip to
//! that thread: a channel message, a wake-up and a context switch each way. On the hot paths (a
//! merge, a lease) those round trips, not SQLite's work, were most of the cost, so the writes of
//! one request go together: on SQLite as one multi-statement query (one round trip; sqlx binds the
//! parameters of all statements from one list), on PostgreSQL one statement after the other, in
//! the order pushed (the documented lock order).

use super::Dialect;
use sqlx::any::AnyRow;

/// A bound value.
pub(super) enum Arg {
    Int(i64),
    Float(f64),
    Text(String),
    Blob(Vec<u8>),
}

impl From<i64> for Arg {
    fn from(v: i64) -> Arg {
        Arg::Int(v)
    }
}

impl From<f64> for Arg {
    fn from(v: f64) -> Arg {
        Arg::Float(v)
    }
}

impl From<&str> for Arg {
    fn from(v: &str) -> Arg {
        Arg::Text(v.to_string())
    }
}

impl From<String> for Arg {
    fn from(v: String) -> Arg {
        Arg::Text(v)
    }
}

impl From<Vec<u8>> for Arg {
    fn from(v: Vec<u8>) -> Arg {
        Arg::Blob(v)
    }
}

/// Statements to run together, each written with its own `$1…$n` parameters.
pub(super) struct Statements {
    dialect: Dialect,
    parts: Vec<(String, Vec<Arg>)>,
}

impl Statements {
    pub fn new(dialect: Dialect) -> Statements {
        Statements {
            dialect,
            parts: Vec::new(),
        }
    }

    /// Adds one statement (a constant of the store's code) and its parameters.
    pub fn push(&mut self, sql: impl Into<String>, args: Vec<Arg>) -> &mut Statements {
        self.parts.push((sql.into(), args));
        self
    }

    /// Runs them in order inside `tx`; the rows any of them return (`RETURNING`), in order.
    pub async fn run(
        self,
        tx: &mut sqlx::Transaction<'static, sqlx::Any>,
    ) -> Result<Vec<AnyRow>, sqlx::Error> {
        match self.dialect {
            Dialect::Sqlite => {
                let mut sql = String::new();
                let mut all = Vec::new();
                for (part, args) in self.parts {
                    if !sql.is_empty() {
                        sql.push_str(";\n");
                    }
                    sql.push_str(&renumber(&part, all.len()));
                    all.extend(args);
                }
                bind(sqlx::query(sqlx::AssertSqlSafe(sql)), all)
                    .fetch_all(&mut **tx)
                    .await
            }
            Dialect::Postgres => {
                let mut rows = Vec::new();
                for (part, args) in self.parts {
                    rows.extend(
                        bind(sqlx::query(sqlx::AssertSqlSafe(part)), args)
                            .fetch_all(&mut **tx)
                            .await?,
                    );
                }
                Ok(rows)
            }
        }
    }
}

fn bind(
    mut q: sqlx::query::Query<'static, sqlx::Any, sqlx::any::AnyArguments>,
    args: Vec<Arg>,
) -> sqlx::query::Query<'static, sqlx::Any, sqlx::any::AnyArguments> {
    for a in args {
        q = match a {
            Arg::Int(v) => q.bind(v),
            Arg::Float(v) => q.bind(v),
            Arg::Text(v) => q.bind(v),
            Arg::Blob(v) => q.bind(v),
        };
    }
    q
}

/// `$k` becomes `$(k + offset)`: in a multi-statement query every `$k` indexes the one parameter
/// list of the whole query. The store's SQL has no `$` anywhere but in parameters.
fn renumber(sql: &str, offset: usize) -> String {
    if offset == 0 {
        return sql.to_string();
    }
    let mut out = String::with_capacity(sql.len() + 8);
    let mut chars = sql.char_indices().peekable();
    while let Some((_, c)) = chars.next() {
        out.push(c);
        if c != '$' {
            continue;
        }
        let mut n = 0usize;
        let mut digits = false;
        while let Some(&(_, d)) = chars.peek() {
            let Some(v) = d.to_digit(10) else { break };
            n = n * 10 + v as usize;
            digits = true;
            chars.next();
        }
        if digits {
            out.push_str(&(n + offset).to_string());
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::renumber;

    #[test]
    fn parameters_are_shifted_past_the_earlier_statements() {
        assert_eq!(
            renumber("UPDATE t SET a = $1, b = $12 WHERE id = $2", 3),
            "UPDATE t SET a = $4, b = $15 WHERE id = $5"
        );
        assert_eq!(renumber("SELECT $1", 0), "SELECT $1");
        assert_eq!(renumber("no parameters", 7), "no parameters");
    }
}
