#include "ukdyn/symbolic/spline.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <string>

#include "core/fnv1a.hpp"
#include "ukdyn/core/types.hpp"
#include "ukdyn/symbolic/expression.hpp"

namespace ukdyn::symbolic {

CubicSpline::CubicSpline(std::vector<double> t, std::vector<double> y, End end, double slope0,
                         double slope1)
    : t_(std::move(t)) {
  const std::size_t n1 = t_.size();
  if (n1 < 2 || y.size() != n1)
    throw Error("a spline needs at least 2 points and as many values as times");
  for (std::size_t i = 0; i < n1; ++i) {
    if (!std::isfinite(t_[i]) || !std::isfinite(y[i]))
      throw Error("spline point " + std::to_string(i + 1) + " is not finite");
    if (i > 0 && !(t_[i] > t_[i - 1]))
      throw Error("spline times must increase strictly (point " + std::to_string(i + 1) + ")");
  }
  if (!std::isfinite(slope0) || !std::isfinite(slope1)) throw Error("spline slopes must be finite");
  const std::size_t n = n1 - 1;  // pieces
  std::vector<double> h(n), lo(n1, 0.0), di(n1, 1.0), up(n1, 0.0), r(n1, 0.0);
  for (std::size_t i = 0; i < n; ++i) h[i] = t_[i + 1] - t_[i];
  auto slope = [&](std::size_t i) { return (y[i + 1] - y[i]) / h[i]; };
  for (std::size_t i = 1; i < n; ++i) {
    lo[i] = h[i - 1];
    di[i] = 2 * (h[i - 1] + h[i]);
    up[i] = h[i];
    r[i] = 6 * (slope(i) - slope(i - 1));
  }
  if (end == End::clamped) {
    di[0] = 2 * h[0];
    up[0] = h[0];
    r[0] = 6 * (slope(0) - slope0);
    lo[n] = h[n - 1];
    di[n] = 2 * h[n - 1];
    r[n] = 6 * (slope1 - slope(n - 1));
  }
  // Thomas algorithm for the second derivatives m (the tridiagonal system of [deBoor1978]).
  for (std::size_t i = 1; i < n1; ++i) {
    const double w = lo[i] / di[i - 1];
    di[i] -= w * up[i - 1];
    r[i] -= w * r[i - 1];
  }
  std::vector<double> m(n1);
  m[n] = r[n] / di[n];
  for (std::size_t i = n; i-- > 0;) m[i] = (r[i] - up[i] * m[i + 1]) / di[i];
  c_.resize(n);
  for (std::size_t i = 0; i < n; ++i) {
    c_[i] = {y[i], slope(i) - h[i] * (2 * m[i] + m[i + 1]) / 6, m[i] / 2,
             (m[i + 1] - m[i]) / (6 * h[i])};
  }
  // Finite knots can still make a spline of no numbers (knots 1e-300 apart, values near the
  // largest double): refused here, where the spline is written, rather than found later as a
  // non-finite residual at the initial state or during the run.
  for (std::size_t i = 0; i < n; ++i) {
    bool finite =
        std::all_of(c_[i].begin(), c_[i].end(), [](double v) { return std::isfinite(v); });
    for (int d = 0; d <= 3 && finite; ++d)
      finite = std::isfinite(eval(t_[i], d)) && std::isfinite(eval(t_[i + 1], d));
    if (!finite)
      throw Error("the spline has no finite polynomial between points " + std::to_string(i + 1) +
                  " and " + std::to_string(i + 2) +
                  " (times too close together for the values, or values too large)");
  }
}

double CubicSpline::eval(double t, int d) const {
  if (d > 3 || d < 0) return 0.0;
  const auto it = std::upper_bound(t_.begin(), t_.end() - 1, t);
  const std::size_t i = it == t_.begin() ? 0 : static_cast<std::size_t>(it - t_.begin()) - 1;
  const std::size_t k = std::min(i, c_.size() - 1);
  const double s = t - t_[k];
  const auto& c = c_[k];
  switch (d) {
    case 0:
      return c[0] + s * (c[1] + s * (c[2] + s * c[3]));
    case 1:
      return c[1] + s * (2 * c[2] + s * 3 * c[3]);
    case 2:
      return 2 * c[2] + 6 * c[3] * s;
    default:
      return 6 * c[3];
  }
}

int CubicSpline::compare(const CubicSpline& o) const {
  auto cmp_bits = [](double x, double y) {
    const auto a = std::bit_cast<std::uint64_t>(x), b = std::bit_cast<std::uint64_t>(y);
    return a < b ? -1 : (a > b ? 1 : 0);
  };
  if (t_.size() != o.t_.size()) return t_.size() < o.t_.size() ? -1 : 1;
  for (std::size_t i = 0; i < t_.size(); ++i) {
    if (const int c = cmp_bits(t_[i], o.t_[i])) return c;
  }
  for (std::size_t i = 0; i < c_.size(); ++i) {
    for (std::size_t k = 0; k < 4; ++k) {
      if (const int c = cmp_bits(c_[i][k], o.c_[i][k])) return c;
    }
  }
  return 0;
}

std::uint64_t CubicSpline::fingerprint() const {
  // FNV-1a, 64 bit, over the bytes of every knot and coefficient (little-endian).
  detail::Fnv1a64 h;
  for (double v : t_) h.add_le64(std::bit_cast<std::uint64_t>(v));
  for (const auto& c : c_) {
    for (double v : c) h.add_le64(std::bit_cast<std::uint64_t>(v));
  }
  return h.value();
}

}  // namespace ukdyn::symbolic

// ---- S: the spline as a GiNaC object (GiNaC's structure<> wrapper around a shared_ptr), compared
// by content so that the canonical order of terms, and the printed output, are the same in every
// process (a pointer order would not be).
namespace ukdyn::symbolic::detail {
struct SplineRef {
  std::shared_ptr<const CubicSpline> spline;
};
template <class T>
class CompareSplineContent {
 protected:
  static bool struct_is_equal(const T* a, const T* b) { return struct_compare(a, b) == 0; }
  static int struct_compare(const T* a, const T* b) {
    if (a->spline == b->spline) return 0;
    if (!a->spline || !b->spline) return a->spline ? 1 : -1;
    return a->spline->compare(*b->spline);
  }
  ~CompareSplineContent() = default;
};
using SplineHandle = GiNaC::structure<SplineRef, CompareSplineContent>;
}  // namespace ukdyn::symbolic::detail

namespace GiNaC {
template <>
void ukdyn::symbolic::detail::SplineHandle::print(const print_context& c,
                                                  unsigned /*level*/) const {
  const auto& s = get_struct().spline;
  char buf[32];
  std::snprintf(buf, sizeof buf, "S_%08llx",
                static_cast<unsigned long long>(s ? (s->fingerprint() & 0xffffffffULL) : 0ULL));
  c.s << buf;
}
}  // namespace GiNaC

namespace ukdyn::symbolic {

namespace {

using detail::SplineHandle;
using GiNaC::ex;

unsigned spline_serial();

ex spline_eval(const ex& id, const ex& order, const ex& t) {
  if (GiNaC::is_a<GiNaC::numeric>(order) && GiNaC::ex_to<GiNaC::numeric>(order).to_int() > 3)
    return 0;
  (void)t;
  return GiNaC::function(spline_serial(), id, order, t).hold();
}

ex spline_evalf(const ex& id, const ex& order, const ex& t) {
  if (!GiNaC::is_a<GiNaC::numeric>(t) || !GiNaC::ex_to<GiNaC::numeric>(t).is_real()) {
    return GiNaC::function(spline_serial(), id, order, t).hold();
  }
  const auto s = spline_of(id);
  return GiNaC::numeric(s->eval(GiNaC::ex_to<GiNaC::numeric>(t).to_double(),
                                GiNaC::ex_to<GiNaC::numeric>(order).to_int()));
}

ex spline_deriv(const ex& id, const ex& order, const ex& t, unsigned param);

unsigned register_spline_function() {
  return GiNaC::function::register_new(GiNaC::function_options("ukdyn_spline", 3)
                                           .eval_func(spline_eval)
                                           .evalf_func(spline_evalf)
                                           .derivative_func(spline_deriv)
                                           .latex_name("\\mathrm{spline}"));
}

// GiNaC's function serial, registered once (constant afterwards).
unsigned spline_serial() {
  static const unsigned serial = register_spline_function();
  return serial;
}

ex spline_deriv(const ex& id, const ex& order, const ex& t, unsigned param) {
  if (param != 2) return 0;
  return GiNaC::function(spline_serial(), id, order + 1, t);
}

}  // namespace

std::shared_ptr<const CubicSpline> spline_of(const ex& handle) {
  if (!GiNaC::is_a<SplineHandle>(handle))
    throw Error("ukdyn_spline: the first argument is no spline");
  const auto& s = GiNaC::ex_to<SplineHandle>(handle).get_struct().spline;
  if (!s) throw Error("ukdyn_spline: empty spline");
  return s;
}

ex spline_expression(const CubicSpline& spline, const ex& arg) {
  const ex handle = SplineHandle(detail::SplineRef{std::make_shared<const CubicSpline>(spline)});
  return GiNaC::function(spline_serial(), handle, 0, arg);
}

}  // namespace ukdyn::symbolic
