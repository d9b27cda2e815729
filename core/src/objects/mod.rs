//! Object parameterization (placeholder docs, filled in below).

pub mod lsd;

/// Errors of the objects module.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ObjectsError {
    /// An image buffer does not match its size.
    #[error("image buffer holds {actual} samples, expected {expected}")]
    BadImage {
        /// width × height.
        expected: usize,
        /// Buffer length.
        actual: usize,
    },
    /// A configuration field is out of range.
    #[error("config {field}: {reason}")]
    BadConfig {
        /// Field name.
        field: &'static str,
        /// What is wrong.
        reason: String,
    },
}
