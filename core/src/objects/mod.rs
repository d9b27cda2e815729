//! Object parameterization (placeholder docs, filled in below).

pub mod iforest;
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
    /// Too few points for the estimator.
    #[error("too few points: {actual} < {required}")]
    TooFewPoints {
        /// Minimum count.
        required: usize,
        /// Count given.
        actual: usize,
    },
    /// A point has a non-finite coordinate.
    #[error("point {index} has a non-finite coordinate")]
    NonFinitePoint {
        /// Index in the input.
        index: usize,
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
