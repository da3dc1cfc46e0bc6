//! Declaring a stage config once: every field's doc, default and valid range are written in
//! one place ([`stage_config!`]), and the rustdoc line, the `Default` impl, the check and the
//! error message all come from that declaration.

use super::ParamError;

/// A check on one parameter value; `describe` is both the rustdoc range and the error message.
pub trait Check<T: ?Sized> {
    fn ok(&self, v: &T) -> bool;
    fn describe(&self) -> String;
    /// The value as printed in an error.
    fn show(&self, v: &T) -> String;

    fn check(&self, field: &'static str, v: &T) -> Result<(), ParamError> {
        if self.ok(v) {
            Ok(())
        } else {
            Err(ParamError {
                field,
                value: self.show(v),
                expected: format!("expected {}", self.describe()),
            })
        }
    }
}

/// A finite number in `lo..=hi` (`lo_open`: `lo` itself excluded), in `unit`.
#[derive(Clone, Copy, Debug)]
pub struct Within {
    pub lo: f64,
    pub hi: f64,
    pub lo_open: bool,
    pub unit: &'static str,
}

/// `lo..=hi`, `unit` (e.g. "mm", "x resolution", "" for a plain number).
pub const fn within(lo: f64, hi: f64, unit: &'static str) -> Within {
    Within {
        lo,
        hi,
        lo_open: false,
        unit,
    }
}

/// `(0, hi]`, `unit`.
pub const fn positive(hi: f64, unit: &'static str) -> Within {
    Within {
        lo: 0.0,
        hi,
        lo_open: true,
        unit,
    }
}

impl Within {
    fn contains(&self, v: f64) -> bool {
        v.is_finite()
            && v <= self.hi
            && if self.lo_open {
                v > self.lo
            } else {
                v >= self.lo
            }
    }

    fn range(&self) -> String {
        let unit = if self.unit.is_empty() {
            String::new()
        } else {
            format!(" {}", self.unit)
        };
        if self.lo_open {
            format!("({}, {}]{unit}", self.lo, self.hi)
        } else {
            format!("{}-{}{unit}", self.lo, self.hi)
        }
    }
}

impl Check<f64> for Within {
    fn ok(&self, v: &f64) -> bool {
        self.contains(*v)
    }
    fn describe(&self) -> String {
        self.range()
    }
    fn show(&self, v: &f64) -> String {
        v.to_string()
    }
}

/// A non-empty list of at most 1000 values, each within the range.
#[derive(Clone, Copy, Debug)]
pub struct List(pub Within);

/// A list of values in `(0, hi]`, `unit`.
pub const fn list(hi: f64, unit: &'static str) -> List {
    List(positive(hi, unit))
}

impl Check<Vec<f64>> for List {
    fn ok(&self, v: &Vec<f64>) -> bool {
        !v.is_empty() && v.len() <= 1000 && v.iter().all(|x| self.0.contains(*x))
    }
    fn describe(&self) -> String {
        format!("a non-empty list of values in {}", self.0.range())
    }
    fn show(&self, v: &Vec<f64>) -> String {
        format!("{v:?}")
    }
}

/// A whole number in `lo..=hi`.
#[derive(Clone, Copy, Debug)]
pub struct Count {
    pub lo: u64,
    pub hi: u64,
    pub unit: &'static str,
}

/// `lo..=hi`, `unit`.
pub const fn count(lo: u64, hi: u64, unit: &'static str) -> Count {
    Count { lo, hi, unit }
}

impl Count {
    fn describe_range(&self) -> String {
        let unit = if self.unit.is_empty() {
            String::new()
        } else {
            format!(" {}", self.unit)
        };
        format!("{}-{}{unit}", self.lo, self.hi)
    }
}

macro_rules! count_check {
    ($($t:ty),*) => {$(
        impl Check<$t> for Count {
            fn ok(&self, v: &$t) -> bool {
                u64::try_from(*v).is_ok_and(|v| (self.lo..=self.hi).contains(&v))
            }
            fn describe(&self) -> String {
                self.describe_range()
            }
            fn show(&self, v: &$t) -> String {
                v.to_string()
            }
        }
    )*};
}
count_check!(u32, u64, usize);

/// `None`, or a count in range.
impl Check<Option<u64>> for Count {
    fn ok(&self, v: &Option<u64>) -> bool {
        v.is_none_or(|v| (self.lo..=self.hi).contains(&v))
    }
    fn describe(&self) -> String {
        format!("none or {}", self.describe_range())
    }
    fn show(&self, v: &Option<u64>) -> String {
        format!("{v:?}")
    }
}

/// `None` (derived automatically), or a value the inner check accepts.
#[derive(Clone, Copy, Debug)]
pub struct Auto<C>(pub C);

/// `None` (auto) or a value within the inner check.
pub const fn auto<C>(inner: C) -> Auto<C> {
    Auto(inner)
}

impl<T, C: Check<T>> Check<Option<T>> for Auto<C> {
    fn ok(&self, v: &Option<T>) -> bool {
        v.as_ref().is_none_or(|v| self.0.ok(v))
    }
    fn describe(&self) -> String {
        format!("auto (unset) or {}", self.0.describe())
    }
    fn show(&self, v: &Option<T>) -> String {
        v.as_ref().map_or_else(|| "auto".into(), |v| self.0.show(v))
    }
}

/// Three finite numbers (`nonzero`: not all zero).
#[derive(Clone, Copy, Debug)]
pub struct Vec3 {
    pub nonzero: bool,
}

/// Three finite numbers.
pub const fn vec3() -> Vec3 {
    Vec3 { nonzero: false }
}

/// Three finite numbers, not all zero (a direction).
pub const fn direction() -> Vec3 {
    Vec3 { nonzero: true }
}

impl Check<[f64; 3]> for Vec3 {
    fn ok(&self, v: &[f64; 3]) -> bool {
        let norm = v.iter().map(|c| c * c).sum::<f64>().sqrt();
        v.iter().all(|c| c.is_finite()) && (!self.nonzero || norm > 1e-9)
    }
    fn describe(&self) -> String {
        if self.nonzero {
            "three finite numbers, not all zero".into()
        } else {
            "three finite numbers".into()
        }
    }
    fn show(&self, v: &[f64; 3]) -> String {
        format!("{v:?}")
    }
}

/// Any value of the type (switches, enums, nested tables with their own `validate`).
#[derive(Clone, Copy, Debug)]
pub struct Any;

/// Any value of the type.
pub const fn any() -> Any {
    Any
}

impl<T: ?Sized> Check<T> for Any {
    fn ok(&self, _: &T) -> bool {
        true
    }
    fn describe(&self) -> String {
        "any value".into()
    }
    fn show(&self, _: &T) -> String {
        String::new()
    }
}

/// Declares a stage config: a struct whose fields each carry their doc, default and check:
///
/// ```text
/// stage_config! {
///     /// Doc of the struct.
///     pub struct Clustering {
///         /// Doc of the field (thesis section).
///         cluster_tolerance_factor: f64 = 1.5, within(1.0, 10.0, "x resolution");
///     }
/// }
/// ```
///
/// Each field's rustdoc gets a line "Default `1.5`; range 1-10 x resolution." built from the
/// same default and check that `Default` and `validate` use, so the three never disagree.
macro_rules! stage_config {
    (
        $(#[$meta:meta])*
        pub struct $name:ident {
            $(
                $(#[doc = $doc:literal])*
                $(#[serde($($serde:tt)*)])?
                $field:ident : $ty:ty = $default:expr, $check:expr;
            )*
        }
    ) => {
        #[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
        $(#[$meta])*
        #[serde(default)]
        pub struct $name {
            $(
                $(#[doc = $doc])*
                #[doc = ""]
                #[doc = concat!("Default `", stringify!($default), "`; check `", stringify!($check), "`.")]
                $(#[serde($($serde)*)])?
                pub $field: $ty,
            )*
        }

        impl Default for $name {
            fn default() -> Self {
                Self { $($field: $default,)* }
            }
        }

        impl $name {
            /// Rejects any value outside its declared range, naming the field.
            pub fn validate(&self) -> Result<(), $crate::params::ParamError> {
                #[allow(unused_imports)]
                use $crate::params::spec::*;
                $( Check::check(&$check, stringify!($field), &self.$field)?; )*
                Ok(())
            }
        }
    };
}
pub(crate) use stage_config;
