#include "ukdyn/symbolic/canonical.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <string>

#include "core/fnv1a.hpp"
#include "ukdyn/core/types.hpp"

namespace ukdyn::symbolic {

namespace {

using GiNaC::ex;
using GiNaC::ex_to;
using GiNaC::is_a;

enum Tag : int { kNumeric = 1, kConstant, kSymbol, kFunction, kPower, kMul, kAdd, kOther };

int tag(const ex& e) {
  if (is_a<GiNaC::numeric>(e)) return kNumeric;
  if (is_a<GiNaC::constant>(e)) return kConstant;
  if (is_a<GiNaC::symbol>(e)) return kSymbol;
  if (is_a<GiNaC::function>(e)) return kFunction;
  if (is_a<GiNaC::power>(e)) return kPower;
  if (is_a<GiNaC::mul>(e)) return kMul;
  if (is_a<GiNaC::add>(e)) return kAdd;
  return kOther;
}

std::uint64_t mix(std::uint64_t h, std::uint64_t x) {  // splitmix64 finaliser of h ^ x
  std::uint64_t z = h ^ (x + 0x9e3779b97f4a7c15ull + (h << 6) + (h >> 2));
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
  return z ^ (z >> 31);
}

std::string printed(const ex& e) {
  std::ostringstream os;
  os << e;
  return os.str();
}

// Names that identify a leaf or a function (exact numbers print exactly: 3/2, -7).
std::string label(const ex& e) {
  switch (tag(e)) {
    case kSymbol:
      return ex_to<GiNaC::symbol>(e).get_name();
    case kFunction:
      return ex_to<GiNaC::function>(e).get_name();
    case kNumeric:
    case kConstant:
      return printed(e);
    case kOther:
      return ex_to<GiNaC::basic>(e).class_name();
    default:
      return {};
  }
}

bool commutative(int t) { return t == kMul || t == kAdd; }

}  // namespace

ex exact_rational(double v) {
  if (!std::isfinite(v)) throw Error("a number must be finite");
  if (v == 0.0) return 0;
  int e = 0;
  const double m = std::frexp(v, &e);                      // v = m · 2^e, 0.5 <= |m| < 1
  const auto mant = static_cast<long>(std::ldexp(m, 53));  // exact: 53 bits
  return GiNaC::numeric(mant) * GiNaC::pow(GiNaC::numeric(2), e - 53);
}

namespace {
struct RoundLong : GiNaC::map_function {
  long max_bits;
  explicit RoundLong(long bits) : max_bits(bits) {}
  ex operator()(const ex& e) override {
    if (GiNaC::is_a<GiNaC::numeric>(e)) {
      const GiNaC::numeric& n = GiNaC::ex_to<GiNaC::numeric>(e);
      if (n.is_rational() && !n.is_integer() &&
          n.numer().int_length() + n.denom().int_length() > max_bits) {
        const double v = n.to_double();
        if (std::isfinite(v)) return exact_rational(v);
      }
      return e;
    }
    return e.nops() == 0 ? e : e.map(*this);
  }
};
}  // namespace

ex round_long_rationals(const ex& e, long max_bits) {
  RoundLong r(max_bits);
  return r(e);
}

std::uint64_t StructuralOrder::hash(const ex& e) {
  if (auto it = memo_.find(e); it != memo_.end()) return it->second;
  const int t = tag(e);
  std::uint64_t h = mix(static_cast<std::uint64_t>(t), detail::ukdyn_hash(label(e)));
  if (commutative(t)) {
    std::vector<std::uint64_t> hs;
    hs.reserve(e.nops());
    for (std::size_t i = 0; i < e.nops(); ++i) hs.push_back(hash(e.op(i)));
    std::sort(hs.begin(), hs.end());
    for (std::uint64_t x : hs) h = mix(h, x);
  } else if (t != kNumeric && t != kConstant && t != kSymbol) {
    for (std::size_t i = 0; i < e.nops(); ++i) h = mix(h, hash(e.op(i)));
  }
  h = mix(h, e.nops());
  memo_.emplace(e, h);
  return h;
}

int StructuralOrder::compare(const ex& a, const ex& b) {
  const std::uint64_t ha = hash(a), hb = hash(b);
  if (ha != hb) return ha < hb ? -1 : 1;
  // Equal hashes: structurally equal, or (rarely) a collision. Compare fully.
  const int ta = tag(a), tb = tag(b);
  if (ta != tb) return ta < tb ? -1 : 1;
  if (ta == kNumeric) return ex_to<GiNaC::numeric>(a).compare(ex_to<GiNaC::numeric>(b));
  const std::string la = label(a), lb = label(b);
  if (la != lb) return la < lb ? -1 : 1;
  if (a.nops() != b.nops()) return a.nops() < b.nops() ? -1 : 1;
  if (ta == kConstant || ta == kSymbol) return 0;
  if (commutative(ta)) {
    const std::vector<ex> oa = sorted_operands(a), ob = sorted_operands(b);
    for (std::size_t i = 0; i < oa.size(); ++i) {
      if (const int c = compare(oa[i], ob[i]); c != 0) return c;
    }
    return 0;
  }
  for (std::size_t i = 0; i < a.nops(); ++i) {
    if (const int c = compare(a.op(i), b.op(i)); c != 0) return c;
  }
  return 0;
}

std::vector<ex> StructuralOrder::sorted_operands(const ex& e) {
  std::vector<ex> ops;
  ops.reserve(e.nops());
  for (std::size_t i = 0; i < e.nops(); ++i) ops.push_back(e.op(i));
  for (const ex& o : ops) (void)hash(o);  // fill the memo before sorting
  std::stable_sort(ops.begin(), ops.end(),
                   [this](const ex& x, const ex& y) { return compare(x, y) < 0; });
  return ops;
}

}  // namespace ukdyn::symbolic
