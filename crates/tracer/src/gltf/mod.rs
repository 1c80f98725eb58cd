//! glTF 2.0 loading.
