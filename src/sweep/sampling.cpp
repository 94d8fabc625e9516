// The parameter values of a sample: grid and list rows, and the counter-based random streams of a
// random sweep (docs/sweeps.md).
#include "sweep/sampling.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <numbers>
#include <vector>

#include "ukdyn/sweep/sweep.hpp"

namespace ukdyn {

// ---------------------------------------------------------------------------------------------
// Counter-based random streams. Every draw is a hash of (seed, sample, parameter, draw): no state
// is carried from one sample to the next, so any subset of samples can be computed anywhere.

std::uint64_t splitmix64(std::uint64_t x) {
  // SplitMix64's output function ([Steele2014], the constants of its reference implementation).
  x += 0x9e3779b97f4a7c15ull;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ull;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebull;
  return x ^ (x >> 31);
}

double sweep_uniform(std::uint64_t seed, long sample, int parameter, int draw) {
  std::uint64_t h = splitmix64(seed);
  h = splitmix64(h ^ static_cast<std::uint64_t>(sample));
  h = splitmix64(h ^
                 (static_cast<std::uint64_t>(parameter) << 32 | static_cast<std::uint32_t>(draw)));
  return static_cast<double>(h >> 11) * 0x1p-53;  // 53 bits: exactly representable, in [0, 1)
}

double sweep_normal(std::uint64_t seed, long sample, int parameter) {
  // Box–Muller ([Box1958]); u1 in (0, 1] so that the logarithm is finite.
  const double u1 = 1.0 - sweep_uniform(seed, sample, parameter, 0);
  const double u2 = sweep_uniform(seed, sample, parameter, 1);
  return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * std::numbers::pi * u2);
}

double sweep_detail::normal_cdf(double x) { return 0.5 * std::erfc(-x / std::numbers::sqrt2); }

namespace {

using sweep_detail::normal_cdf;

// A normal(mean, sd) deviate restricted to [low, high] by the inverse distribution function: u is
// mapped onto [Φ(a), Φ(b)] and Φ⁻¹ found by bisection (deterministic: only erfc and halving).
double truncated_normal(double u, double mean, double sd, double low, double high) {
  double a = std::max((low - mean) / sd, -40.0), b = std::min((high - mean) / sd, 40.0);
  const bool flip = a > 0.0;  // the upper tail: work on the mirrored lower one (more precision)
  if (flip) {
    const double t = a;
    a = -b;
    b = -t;
  }
  const double pa = normal_cdf(a), pb = normal_cdf(b);
  const double p = pa + u * (pb - pa);
  double lo = a, hi = b;
  for (int i = 0; i < 200 && lo < hi; ++i) {
    const double mid = 0.5 * (lo + hi);
    if (mid <= lo || mid >= hi) break;
    (normal_cdf(mid) < p ? lo : hi) = mid;
  }
  const double z = flip ? -0.5 * (lo + hi) : 0.5 * (lo + hi);
  return std::clamp(mean + sd * z, low, high);
}

}  // namespace

std::vector<double> sample_values(const Sweep& sw, long k) {
  std::vector<double> v(sw.parameters.size());
  long rest = k;
  // Grid: the last parameter varies fastest (row-major order).
  for (std::size_t j = sw.parameters.size(); j-- > 0;) {
    const auto& p = sw.parameters[j];
    const auto& d = p.dist;
    const int pj = static_cast<int>(j);
    switch (sw.mode) {
      case Sweep::Mode::grid: {
        const long n = static_cast<long>(d.values.size());
        v[j] = d.values[static_cast<std::size_t>(rest % n)];
        rest /= n;
        break;
      }
      case Sweep::Mode::list:
        v[j] = d.values[static_cast<std::size_t>(k)];
        break;
      case Sweep::Mode::random:
        switch (d.kind) {
          case SweepDistribution::Kind::uniform: {
            const double u = sweep_uniform(sw.seed, k, pj, 0);
            v[j] = d.low + (d.high - d.low) * u;
            break;
          }
          case SweepDistribution::Kind::normal:
            v[j] = d.mean + d.sd * sweep_normal(sw.seed, k, pj);
            break;
          case SweepDistribution::Kind::truncated_normal:
            v[j] = truncated_normal(sweep_uniform(sw.seed, k, pj, 0), d.mean, d.sd, d.low, d.high);
            break;
          case SweepDistribution::Kind::values:
            v[j] = 0.0;
            break;
        }
        break;
    }
  }
  return v;
}

}  // namespace ukdyn
