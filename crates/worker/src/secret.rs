//! [`Secret`]: a string that must not be printed (a token, a worker credential, a database URL with
//! its password). Its `Debug` is `"***"` and it has no `Display`: the one way to its text is
//! [`Secret::expose`], where it is sent.

use serde::{Deserialize, Serialize};

/// A secret string: `Debug` prints `"***"`.
#[derive(Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(transparent)]
pub struct Secret(String);

impl Secret {
    pub fn new(text: impl Into<String>) -> Secret {
        Secret(text.into())
    }
    /// The secret's text, for where it is used (a header, a connection).
    pub fn expose(&self) -> &str {
        &self.0
    }
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
}

impl std::fmt::Debug for Secret {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("\"***\"")
    }
}

impl From<String> for Secret {
    fn from(s: String) -> Secret {
        Secret(s)
    }
}

impl From<&str> for Secret {
    fn from(s: &str) -> Secret {
        Secret(s.to_string())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn debug_redacts_and_serde_is_the_plain_string() {
        let s = Secret::from("w-77a0");
        assert_eq!(format!("{s:?}"), "\"***\"");
        assert_eq!(format!("{:?}", Some(vec![s.clone()])), "Some([\"***\"])");
        assert_eq!(s.expose(), "w-77a0");
        assert_eq!(serde_json::to_string(&s).unwrap(), "\"w-77a0\"");
        let back: Secret = serde_json::from_str("\"w-77a0\"").unwrap();
        assert_eq!(back, s);
    }
}
