"""Python peer of the GMWM fit benchmark: numpy prefix-sum Haar WV (same estimator as
dynacal: boundary coefficients dropped, J = floor(log2 N) - 1, eta3 weights) and a WN + 2 GM
fit by scipy.optimize.least_squares (trust-region reflective, analytic-free: 2-point finite
differences) on log parameters from dynacal's own starting grid idea (one fixed start
here: beta at the shortest and longest scales), with delta-method intervals from J'J.
Usage: fit_bench.py SERIES.f64"""
import sys, time
import numpy as np
from scipy.optimize import least_squares
from scipy.stats import chi2

x = np.fromfile(sys.argv[1], dtype="<f8")
n = len(x); dt = 0.01
t0 = time.perf_counter()
s = np.concatenate(([0.0], np.cumsum(x - x.mean())))
J = int(np.floor(np.log2(n))) - 1
levels = np.arange(1, J + 1); nu = np.empty(J); m = np.empty(J)
for i, j in enumerate(levels):
    h = 2 ** (j - 1); tau = 2 * h
    w = (s[tau:] - 2 * s[h:n + 1 - h] + s[:n + 1 - tau]) / tau
    nu[i] = np.mean(w * w); m[i] = len(w)
eta = np.maximum(m / 2.0 ** levels, 1.0)
lo = eta * nu / chi2.ppf(0.975, eta); hi = eta * nu / chi2.ppf(0.025, eta)
omega = 1.0 / ((hi - lo) / (2 * 1.959963984540054)) ** 2
t1 = time.perf_counter()
tau = 2.0 ** levels
def model(th):
    out = np.exp(th[0]) / tau
    for k in (1, 3):
        a = np.exp(th[k]) * dt; s2 = np.exp(th[k + 1]); phi = np.exp(-a); h = tau / 2
        b = h * (1 - phi**2) - 3 * phi + 4 * phi**(h + 1) - phi**(2 * h + 1)
        out = out + 2 * s2 * b / ((1 - phi) ** 2 * tau**2)
    return out
res = lambda th: np.sqrt(omega) * (nu - model(th))
th0 = np.array([np.log(2 * nu[0]), np.log(1 / (tau[-1] * dt)), np.log(nu[-1]), np.log(1 / (8 * dt)), np.log(nu[0])])
r = least_squares(res, th0, method="trf", xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=5000)
jac = r.jac; cov = np.linalg.pinv(jac.T @ jac); se = np.sqrt(np.diag(cov))
ci = np.exp(np.vstack([r.x - 1.96 * se, r.x + 1.96 * se]))
t2 = time.perf_counter()
p = np.exp(r.x)
print(f"python n={n} wv_s={t1-t0:.4f} fit_with_intervals_s={t2-t1:.4f} objective={2*r.cost:.4e} status={r.status} "
      f"WN={p[0]:.5e} GM1.beta={p[1]:.5e} GM1.sigma2={p[2]:.5e} GM2.beta={p[3]:.5e} GM2.sigma2={p[4]:.5e}")
