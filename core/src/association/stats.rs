//! Hypothesis tests used by the association: Mann-Whitney U (Wilcoxon rank-sum) with the
//! tie-corrected normal approximation, the one-sample t-test and the two-sample pooled-variance
//! t-test. All three are two-sided and agree with scipy.stats to ~1e-12 where scipy returns finite
//! values (fixture `core/tests/fixtures/stats.json`, written by `make_stats.py` beside it):
//!
//! - [`mann_whitney_u`] = `scipy.stats.mannwhitneyu(x, y, alternative="two-sided",
//!   method="asymptotic", use_continuity=...)`; the statistic returned is scipy's `U1` (for `x`).
//! - [`ttest_1samp`] = `scipy.stats.ttest_1samp(a, popmean)`.
//! - [`ttest_ind`] = `scipy.stats.ttest_ind(a, b, equal_var=True)`.
//!
//! Where scipy returns NaN or ±inf these functions return a typed [`StatsError`] instead (too few
//! samples, zero variance, non-finite input); callers decide what that means (the association
//! treats such a test as "not applicable", which never counts as a pass). One exception, stated:
//! Mann-Whitney with every value tied (zero rank variance) returns p = 1 with either continuity
//! setting: the two samples are indistinguishable (scipy gives 1 with continuity, NaN without).
//!
//! Two-sided p-values use the complementary functions directly (`erfc` for the normal,
//! the regularized incomplete beta for Student's t, from statrs) so tiny p-values keep their
//! relative precision.

use statrs::function::beta::beta_reg;
use statrs::function::erf::erfc;

/// Errors of the statistical tests (cases where scipy would return NaN or ±inf).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum StatsError {
    /// A sample is too small for the test.
    #[error("{sample}: {actual} values, the test needs at least {required}")]
    TooFewSamples {
        /// Which sample (`"x"`, `"y"`, `"a"`, `"b"`).
        sample: &'static str,
        /// Minimum size.
        required: usize,
        /// Size given.
        actual: usize,
    },
    /// The sample variance (or pooled variance) is zero, so the t statistic is undefined or
    /// infinite.
    #[error("zero variance: the t statistic is undefined")]
    ZeroVariance,
    /// A value is NaN or infinite.
    #[error("{sample}: non-finite value at index {index}")]
    NonFinite {
        /// Which sample.
        sample: &'static str,
        /// Index of the first offending value.
        index: usize,
    },
}

/// Result of a two-sided test: the statistic and its p-value in [0, 1].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TestResult {
    /// Test statistic (Mann-Whitney: `U1` of the first sample; t-tests: `t`).
    pub statistic: f64,
    /// Two-sided p-value.
    pub p_value: f64,
}

fn check_finite(sample: &'static str, v: &[f64]) -> Result<(), StatsError> {
    match v.iter().position(|x| !x.is_finite()) {
        Some(index) => Err(StatsError::NonFinite { sample, index }),
        None => Ok(()),
    }
}

fn check_len(sample: &'static str, v: &[f64], required: usize) -> Result<(), StatsError> {
    if v.len() < required {
        return Err(StatsError::TooFewSamples { sample, required, actual: v.len() });
    }
    Ok(())
}

/// Two-sided p-value of a standard normal statistic `z`: `P(|Z| ≥ |z|)`.
pub fn normal_two_sided_p(z: f64) -> f64 {
    erfc(z.abs() / std::f64::consts::SQRT_2).clamp(0.0, 1.0)
}

/// Two-sided p-value of Student's t with `df` degrees of freedom: `P(|T| ≥ |t|)`
/// = `I_{df/(df+t²)}(df/2, 1/2)`. `df` must be positive; `t = ±inf` gives 0.
pub fn student_t_two_sided_p(t: f64, df: f64) -> f64 {
    if t.is_infinite() {
        return 0.0;
    }
    let h = df / (df + t * t);
    beta_reg(df / 2.0, 0.5, h).clamp(0.0, 1.0)
}

/// A `u64` whose integer order is the numeric order of finite `f64`s (−0.0 and +0.0 map to the
/// same key, so they tie as in scipy). Sorting integers is faster than `f64::total_cmp`.
pub fn order_key(v: f64) -> u64 {
    let bits = (v + 0.0).to_bits(); // −0.0 + 0.0 = +0.0
    if bits >> 63 == 1 {
        !bits
    } else {
        bits | (1 << 63)
    }
}

/// Mann-Whitney U statistic pieces from two samples *already sorted ascending* (no NaN; any
/// ordered type: `f64`, or the keys of [`order_key`]):
/// `(U1, tie_term)` with `tie_term = Σ (t³ − t)` over tie groups of the pooled sample.
///
/// Merges the two sorted lists in one pass (O(|x| + |y|)); ranks of tied values are averaged.
pub fn rank_sum_sorted<T: PartialOrd + Copy>(x_sorted: &[T], y_sorted: &[T]) -> (f64, f64) {
    let (n1, n2) = (x_sorted.len(), y_sorted.len());
    let (mut i, mut j) = (0usize, 0usize);
    let mut rank_sum_x = 0.0f64;
    let mut tie_term = 0.0f64;
    let mut next_rank = 1usize; // rank of the next value in the pooled order (1-based)
    while i < n1 || j < n2 {
        // Smallest remaining value.
        let v = match (x_sorted.get(i), y_sorted.get(j)) {
            (Some(a), Some(b)) => {
                if b < a {
                    *b
                } else {
                    *a
                }
            }
            (Some(a), None) => *a,
            (None, Some(b)) => *b,
            (None, None) => break,
        };
        let mut cx = 0usize;
        while i < n1 && x_sorted[i] == v {
            i += 1;
            cx += 1;
        }
        let mut cy = 0usize;
        while j < n2 && y_sorted[j] == v {
            j += 1;
            cy += 1;
        }
        let t = cx + cy;
        if t == 0 {
            // Unsorted input; cannot happen with ascending samples. Stop rather than loop.
            break;
        }
        // Average rank of the tie group: next_rank .. next_rank + t − 1.
        let avg = next_rank as f64 + (t as f64 - 1.0) / 2.0;
        rank_sum_x += avg * cx as f64;
        if t > 1 {
            let tf = t as f64;
            tie_term += tf * tf * tf - tf;
        }
        next_rank += t;
    }
    let u1 = rank_sum_x - (n1 * (n1 + 1)) as f64 / 2.0;
    (u1, tie_term)
}

/// Two-sided p-value of the Mann-Whitney test from `U1`, the sample sizes and the tie term
/// (scipy's `_get_mwu_z` + `2 · norm.sf`, clipped to 1). Every value tied → p = 1 (see module docs).
pub fn mann_whitney_p(u1: f64, n1: usize, n2: usize, tie_term: f64, use_continuity: bool) -> f64 {
    let (n1f, n2f) = (n1 as f64, n2 as f64);
    let n = n1f + n2f;
    let mu = n1f * n2f / 2.0;
    let u = u1.max(n1f * n2f - u1);
    let var = n1f * n2f / 12.0 * ((n + 1.0) - tie_term / (n * (n - 1.0)));
    if var.is_nan() || var <= 0.0 {
        return 1.0;
    }
    let mut num = u - mu;
    if use_continuity {
        num -= 0.5;
    }
    let z = num / var.sqrt();
    if z <= 0.0 {
        // 2 · sf(z) ≥ 1 → clipped to 1, as scipy does.
        return 1.0;
    }
    normal_two_sided_p(z)
}

/// Two-sided Mann-Whitney U test (Wilcoxon rank-sum), normal approximation with the
/// tie-corrected variance `n1·n2/12 · ((n+1) − Σ(t³−t)/(n(n−1)))`.
///
/// Matches `scipy.stats.mannwhitneyu(x, y, alternative="two-sided", method="asymptotic",
/// use_continuity=use_continuity)`; `statistic` is scipy's `U1`. Both samples need ≥ 1 value.
pub fn mann_whitney_u(x: &[f64], y: &[f64], use_continuity: bool) -> Result<TestResult, StatsError> {
    check_len("x", x, 1)?;
    check_len("y", y, 1)?;
    check_finite("x", x)?;
    check_finite("y", y)?;
    let mut xs: Vec<u64> = x.iter().map(|v| order_key(*v)).collect();
    let mut ys: Vec<u64> = y.iter().map(|v| order_key(*v)).collect();
    xs.sort_unstable();
    ys.sort_unstable();
    let (u1, tie_term) = rank_sum_sorted(&xs, &ys);
    Ok(TestResult { statistic: u1, p_value: mann_whitney_p(u1, xs.len(), ys.len(), tie_term, use_continuity) })
}

/// Mean and unbiased variance (ddof = 1) of a slice (two-pass, as numpy); the variance of a
/// single value is 0 and the mean of an empty slice is NaN.
pub fn mean_var(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let ss = v.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>();
    (mean, if v.len() > 1 { ss / (n - 1.0) } else { 0.0 })
}

/// Two-sided one-sample t-test of `H0: mean(a) = popmean`; `t = (m(a) − popmean) / (s/√n)`,
/// `n − 1` degrees of freedom. Matches `scipy.stats.ttest_1samp(a, popmean)`.
///
/// Errors: fewer than 2 values ([`StatsError::TooFewSamples`]), zero sample variance
/// ([`StatsError::ZeroVariance`]; scipy gives ±inf or NaN), non-finite values.
pub fn ttest_1samp(a: &[f64], popmean: f64) -> Result<TestResult, StatsError> {
    check_len("a", a, 2)?;
    check_finite("a", a)?;
    if !popmean.is_finite() {
        return Err(StatsError::NonFinite { sample: "popmean", index: 0 });
    }
    let (mean, var) = mean_var(a);
    if var.is_nan() || var <= 0.0 {
        return Err(StatsError::ZeroVariance);
    }
    let n = a.len() as f64;
    let t = (mean - popmean) / (var / n).sqrt();
    Ok(TestResult { statistic: t, p_value: student_t_two_sided_p(t, n - 1.0) })
}

/// Two-sided two-sample t-test with pooled variance (the paper's D-t test):
/// `t = (m(a) − m(b)) / √(s_p² (1/n_a + 1/n_b))`, `s_p² = ((n_a−1)s_a² + (n_b−1)s_b²)/(n_a+n_b−2)`,
/// `n_a + n_b − 2` degrees of freedom. Matches `scipy.stats.ttest_ind(a, b, equal_var=True)`.
///
/// Errors: an empty sample, or fewer than 3 values in all (no degree of freedom; scipy: NaN), zero
/// pooled variance (scipy: ±inf or NaN), non-finite values. A sample of one value contributes no
/// variance, as in scipy.
pub fn ttest_ind(a: &[f64], b: &[f64]) -> Result<TestResult, StatsError> {
    check_len("a", a, 1)?;
    check_len("b", b, 1)?;
    check_finite("a", a)?;
    check_finite("b", b)?;
    let (ma, va) = mean_var(a);
    let (mb, vb) = mean_var(b);
    pooled_t(ma, va, a.len(), mb, vb, b.len())
}

/// The pooled two-sample t-test from summary statistics (means, ddof-1 variances, sizes ≥ 1 with
/// `na + nb ≥ 3`; the variance of a one-value sample is ignored).
pub fn pooled_t(ma: f64, va: f64, na: usize, mb: f64, vb: f64, nb: usize) -> Result<TestResult, StatsError> {
    if na < 1 {
        return Err(StatsError::TooFewSamples { sample: "a", required: 1, actual: na });
    }
    if nb < 1 {
        return Err(StatsError::TooFewSamples { sample: "b", required: 1, actual: nb });
    }
    if na + nb < 3 {
        return Err(StatsError::TooFewSamples { sample: "a+b", required: 3, actual: na + nb });
    }
    let (naf, nbf) = (na as f64, nb as f64);
    let df = naf + nbf - 2.0;
    let sp2 = ((naf - 1.0) * va + (nbf - 1.0) * vb) / df;
    let denom = (sp2 * (1.0 / naf + 1.0 / nbf)).sqrt();
    if denom.is_nan() || denom <= 0.0 {
        return Err(StatsError::ZeroVariance);
    }
    let t = (ma - mb) / denom;
    Ok(TestResult { statistic: t, p_value: student_t_two_sided_p(t, df) })
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::Value;

    /// Written by `core/tests/fixtures/make_stats.py` (scipy.stats).
    const FIXTURE: &str = include_str!("../../tests/fixtures/stats.json");

    fn fixture() -> Value {
        serde_json::from_str(FIXTURE).unwrap()
    }

    fn floats(v: &Value) -> Vec<f64> {
        v.as_array().expect("not an array").iter().filter_map(Value::as_f64).collect()
    }

    fn close(a: f64, b: f64, what: &str) {
        let tol = 1e-9 * b.abs().max(1e-300);
        assert!((a - b).abs() <= tol || (a - b).abs() < 1e-14, "{what}: ours {a}, scipy {b}");
    }

    #[test]
    fn mann_whitney_matches_scipy() {
        let f = fixture();
        let cases = f["mannwhitneyu"].as_array().expect("cases");
        assert!(cases.len() >= 20);
        for c in cases {
            let name = format!("{} continuity={}", c["name"], c["use_continuity"]);
            let x = floats(&c["x"]);
            let y = floats(&c["y"]);
            let cont = c["use_continuity"].as_bool().unwrap_or(false);
            let r = mann_whitney_u(&x, &y, cont).unwrap();
            close(r.statistic, c["u1"].as_f64().unwrap_or(f64::NAN), &name);
            match c["pvalue"].as_f64() {
                Some(p) => close(r.p_value, p, &name),
                // scipy: NaN when every value is tied and no continuity; ours: p = 1 (documented).
                None => {
                    assert_eq!(c["name"], "all_tied");
                    assert_eq!(r.p_value, 1.0);
                }
            }
        }
    }

    #[test]
    fn ttest_1samp_matches_scipy() {
        let f = fixture();
        for c in f["ttest_1samp"].as_array().expect("cases") {
            let name = c["name"].to_string();
            let a = floats(&c["a"]);
            let m = c["popmean"].as_f64().unwrap_or(f64::NAN);
            let r = ttest_1samp(&a, m);
            match (c["statistic"].as_f64(), c["pvalue"].as_f64()) {
                (Some(t), Some(p)) => {
                    let r = r.unwrap();
                    close(r.statistic, t, &name);
                    close(r.p_value, p, &name);
                }
                _ => match a.len() {
                    0 | 1 => assert!(matches!(r, Err(StatsError::TooFewSamples { .. })), "{name}: {r:?}"),
                    _ => assert_eq!(r, Err(StatsError::ZeroVariance), "{name}"),
                },
            }
        }
    }

    #[test]
    fn ttest_ind_matches_scipy() {
        let f = fixture();
        for c in f["ttest_ind"].as_array().expect("cases") {
            let name = c["name"].to_string();
            let a = floats(&c["x"]);
            let b = floats(&c["y"]);
            let r = ttest_ind(&a, &b);
            match (c["statistic"].as_f64(), c["pvalue"].as_f64()) {
                (Some(t), Some(p)) => {
                    let r = r.unwrap();
                    close(r.statistic, t, &name);
                    close(r.p_value, p, &name);
                }
                _ => {
                    if a.len() + b.len() < 3 {
                        assert!(matches!(r, Err(StatsError::TooFewSamples { .. })), "{name}: {r:?}");
                    } else {
                        assert_eq!(r, Err(StatsError::ZeroVariance), "{name}");
                    }
                }
            }
        }
    }

    #[test]
    fn bad_input_is_a_typed_error() {
        assert_eq!(
            mann_whitney_u(&[], &[1.0], false),
            Err(StatsError::TooFewSamples { sample: "x", required: 1, actual: 0 })
        );
        assert_eq!(
            mann_whitney_u(&[1.0, f64::NAN], &[1.0], false),
            Err(StatsError::NonFinite { sample: "x", index: 1 })
        );
        assert_eq!(ttest_1samp(&[1.0], 0.0), Err(StatsError::TooFewSamples { sample: "a", required: 2, actual: 1 }));
        assert_eq!(ttest_1samp(&[1.0, 2.0], f64::NAN), Err(StatsError::NonFinite { sample: "popmean", index: 0 }));
        assert_eq!(ttest_ind(&[1.0, 1.0], &[1.0, 1.0]), Err(StatsError::ZeroVariance));
        assert_eq!(ttest_ind(&[1.0], &[2.0]), Err(StatsError::TooFewSamples { sample: "a+b", required: 3, actual: 2 }));
        assert_eq!(ttest_ind(&[], &[2.0, 3.0]), Err(StatsError::TooFewSamples { sample: "a", required: 1, actual: 0 }));
        assert!(matches!(
            ttest_ind(&[1.0, 2.0], &[f64::INFINITY, 1.0]),
            Err(StatsError::NonFinite { sample: "b", .. })
        ));
    }

    #[test]
    fn order_keys_sort_like_values() {
        let keys: Vec<u64> = [-2.0, -1e-300, -0.0, 0.0, 1e-300, 3.5, f64::MAX].iter().map(|x| order_key(*x)).collect();
        assert!(keys.windows(2).all(|w| w[0] <= w[1]));
        assert_eq!(keys[2], keys[3], "−0 and +0 tie");
        assert!(keys[1] < keys[2] && keys[3] < keys[4]);
    }

    #[test]
    fn p_value_helpers_match_closed_forms() {
        // P(|Z| ≥ 1.959963984540054) = 0.05.
        close(normal_two_sided_p(1.959963984540054), 0.05, "normal");
        // Student's t with 1 dof is Cauchy: P(|T| ≥ 1) = 0.5.
        close(student_t_two_sided_p(1.0, 1.0), 0.5, "cauchy");
        // With 2 dof: P(|T| ≥ t) = 1 − t/√(2 + t²).
        let t: f64 = 1.5;
        close(student_t_two_sided_p(t, 2.0), 1.0 - t / (2.0 + t * t).sqrt(), "t2");
        assert_eq!(student_t_two_sided_p(f64::INFINITY, 3.0), 0.0);
    }
}
