//! Chi-square distribution for integer degrees of freedom (gating thresholds and NEES bounds).

/// `ln Γ(dof / 2)`, exact by the recursion `Γ(a + 1) = a·Γ(a)` from `Γ(1) = 1` or `Γ(½) = √π`.
fn ln_gamma_half(dof: u32) -> f64 {
    let (mut a, mut value) = if dof.is_multiple_of(2) { (1.0, 0.0) } else { (0.5, 0.5 * core::f64::consts::PI.ln()) };
    let target = f64::from(dof) / 2.0;
    while a < target {
        value += f64::ln(a);
        a += 1.0;
    }
    value
}

/// Regularized lower incomplete gamma `P(a, x)` with `a = dof / 2` (the chi-square CDF at `2x`): a power series below `a + 1`,
/// otherwise a continued fraction for the upper tail (modified Lentz), both converge fast there.
fn regularized_gamma_p(dof: u32, x: f64) -> f64 {
    let a = f64::from(dof) / 2.0;
    if x <= 0.0 {
        return 0.0;
    }
    let log_prefactor = -x + a * x.ln() - ln_gamma_half(dof);
    if x < a + 1.0 {
        let mut term = 1.0 / a;
        let mut sum = term;
        let mut n = a;
        for _ in 0..10_000 {
            n += 1.0;
            term *= x / n;
            sum += term;
            if term.abs() < sum.abs() * 1e-16 {
                break;
            }
        }
        (sum * log_prefactor.exp()).clamp(0.0, 1.0)
    } else {
        let tiny = 1e-300;
        let mut b = x + 1.0 - a;
        let mut c = 1.0 / tiny;
        let mut d = 1.0 / b;
        let mut h = d;
        for i in 1..10_000 {
            let fi = f64::from(i);
            let an = -fi * (fi - a);
            b += 2.0;
            d = an * d + b;
            if d.abs() < tiny {
                d = tiny;
            }
            c = b + an / c;
            if c.abs() < tiny {
                c = tiny;
            }
            d = 1.0 / d;
            let delta = d * c;
            h *= delta;
            if (delta - 1.0).abs() < 1e-16 {
                break;
            }
        }
        (1.0 - log_prefactor.exp() * h).clamp(0.0, 1.0)
    }
}

/// Cumulative distribution `P(X ≤ x)` of a chi-square variable with `dof` degrees of freedom.
pub fn chi2_cdf(dof: u32, x: f64) -> f64 {
    if dof == 0 {
        return if x >= 0.0 { 1.0 } else { 0.0 };
    }
    regularized_gamma_p(dof, 0.5 * x)
}

/// The `probability` quantile of the chi-square distribution (bisection on the CDF; `NaN` for a
/// probability outside `(0, 1)` or zero degrees of freedom).
pub fn chi2_quantile(dof: u32, probability: f64) -> f64 {
    if dof == 0 || !(probability > 0.0 && probability < 1.0) {
        return f64::NAN;
    }
    let mut lo = 0.0;
    let mut hi = f64::from(dof).max(1.0);
    while chi2_cdf(dof, hi) < probability {
        lo = hi;
        hi *= 2.0;
    }
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if chi2_cdf(dof, mid) < probability {
            lo = mid;
        } else {
            hi = mid;
        }
        if hi - lo <= 1e-12 * hi {
            break;
        }
    }
    0.5 * (lo + hi)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_match_tables() {
        // Standard table values (e.g. NIST/SEMATECH e-Handbook 1.3.6.7.4).
        let cases = [
            (1, 0.95, 3.841),
            (3, 0.95, 7.815),
            (6, 0.999, 22.458),
            (3, 0.025, 0.216),
            (3, 0.975, 9.348),
            (60, 0.025, 40.482),
            (60, 0.975, 83.298),
            (2, 0.99, 9.210),
        ];
        for (dof, p, expected) in cases {
            let q = chi2_quantile(dof, p);
            assert!((q - expected).abs() < 1e-3, "dof {dof} p {p}: {q} vs {expected}");
        }
    }
}
