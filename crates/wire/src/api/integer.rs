//! Integers in request bodies, as JSON Schema counts them: `5` and `5.0` are the same integer
//! (`{"type": "integer"}` accepts any number with a zero fractional part), so an integral float is
//! accepted where it is exact and in range; `5.5`, `1e300` and out-of-range values are errors.

use serde::de::{Error, Unexpected, Visitor};
use serde::{Deserialize, Deserializer};
use std::fmt;
use std::marker::PhantomData;

/// Largest integer every f64 below it represents exactly (2^53).
const EXACT: f64 = 9_007_199_254_740_992.0;

struct Exact<T>(PhantomData<T>);

impl<T: TryFrom<i64> + TryFrom<u64>> Visitor<'_> for Exact<T> {
    type Value = T;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        write!(f, "an integer in range for {}", std::any::type_name::<T>())
    }

    fn visit_i64<E: Error>(self, v: i64) -> Result<T, E> {
        T::try_from(v).map_err(|_| E::invalid_value(Unexpected::Signed(v), &self))
    }

    fn visit_u64<E: Error>(self, v: u64) -> Result<T, E> {
        T::try_from(v).map_err(|_| E::invalid_value(Unexpected::Unsigned(v), &self))
    }

    fn visit_f64<E: Error>(self, v: f64) -> Result<T, E> {
        if v.fract() != 0.0 || v.abs() > EXACT {
            return Err(E::invalid_value(Unexpected::Float(v), &self));
        }
        // Integral and at most 2^53 in magnitude: the cast is exact.
        self.visit_i64(v as i64)
    }
}

pub fn deserialize<'de, T, D>(d: D) -> Result<T, D::Error>
where
    T: TryFrom<i64> + TryFrom<u64>,
    D: Deserializer<'de>,
{
    d.deserialize_any(Exact(PhantomData))
}

/// The same for an optional field (`null` or absent is `None`).
pub mod option {
    use super::*;

    pub fn deserialize<'de, T, D>(d: D) -> Result<Option<T>, D::Error>
    where
        T: TryFrom<i64> + TryFrom<u64>,
        D: Deserializer<'de>,
    {
        #[derive(Deserialize)]
        struct Wrap<T: TryFrom<i64> + TryFrom<u64>>(
            #[serde(deserialize_with = "super::deserialize")] T,
        );
        Ok(Option::<Wrap<T>>::deserialize(d)?.map(|Wrap(v)| v))
    }
}
