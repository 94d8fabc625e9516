#include "ukdyn/symbolic/tape.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <map>
#include <sstream>
#include <unordered_set>

#include "core/fnv1a.hpp"
#include "symbolic/tape_work.hpp"
#include "ukdyn/symbolic/canonical.hpp"
#include "ukdyn/symbolic/expression.hpp"
#include "ukdyn/symbolic/spline.hpp"
#include "ukdyn/symbolic/tape_inputs.hpp"

namespace ukdyn::symbolic {

namespace {

using GiNaC::ex;
using GiNaC::ex_to;
using GiNaC::is_a;

inline double apply(Tape::Op op, double x, double y, double imm) {
  using Op = Tape::Op;
  switch (op) {
    case Op::add:
      return x + y;
    case Op::sub:
      return x - y;
    case Op::mul:
      return x * y;
    case Op::div:
      return x / y;
    case Op::neg:
      return -x;
    case Op::add_c:
      return x + imm;
    case Op::mul_c:
      return x * imm;
    case Op::square:
      return x * x;
    case Op::pow:
      return std::pow(x, y);
    case Op::sqrt:
      return std::sqrt(x);
    case Op::sin:
      return std::sin(x);
    case Op::cos:
      return std::cos(x);
    case Op::tan:
      return std::tan(x);
    case Op::asin:
      return std::asin(x);
    case Op::acos:
      return std::acos(x);
    case Op::atan:
      return std::atan(x);
    case Op::atan2:
      return std::atan2(x, y);
    case Op::exp:
      return std::exp(x);
    case Op::log:
      return std::log(x);
    case Op::sinh:
      return std::sinh(x);
    case Op::cosh:
      return std::cosh(x);
    case Op::tanh:
      return std::tanh(x);
    case Op::abs:
      return std::abs(x);
    default:
      return imm;
  }
}

bool is_binary(Tape::Op op) {
  using Op = Tape::Op;
  return op == Op::add || op == Op::sub || op == Op::mul || op == Op::div || op == Op::pow ||
         op == Op::atan2;
}

bool is_commutative(Tape::Op op) { return op == Tape::Op::add || op == Tape::Op::mul; }

double to_double(const ex& e) {
  const ex v = e.evalf();
  if (!is_a<GiNaC::numeric>(v) || !ex_to<GiNaC::numeric>(v).is_real()) {
    std::ostringstream os;
    os << "cannot evaluate '" << e << "' to a real number";
    throw Error(os.str());
  }
  return ex_to<GiNaC::numeric>(v).to_double();
}

}  // namespace

bool Tape::Key::operator<(const Key& o) const {
  if (op != o.op) return op < o.op;
  if (a != o.a) return a < o.a;
  if (b != o.b) return b < o.b;
  return imm_bits < o.imm_bits;
}

std::int32_t Tape::emit(Op op, std::int32_t a, std::int32_t b, double imm) {
  const bool unary_input = op != Op::constant && op != Op::time && op != Op::q && op != Op::qd;
  if (op == Op::spline && code_[static_cast<std::size_t>(a)].op == Op::constant) {
    const auto k = static_cast<std::size_t>(imm);
    return constant(
        splines_[k / 4]->eval(code_[static_cast<std::size_t>(a)].imm, static_cast<int>(k % 4)));
  }
  if (unary_input) {
    // Constant folding.
    const bool ca = code_[static_cast<std::size_t>(a)].op == Op::constant;
    const bool cb = !is_binary(op) || code_[static_cast<std::size_t>(b)].op == Op::constant;
    if (ca && cb) {
      const double x = code_[static_cast<std::size_t>(a)].imm;
      const double y = is_binary(op) ? code_[static_cast<std::size_t>(b)].imm : 0.0;
      return constant(apply(op, x, y, imm));
    }
    if (!is_binary(op)) b = 0;
    if (is_commutative(op) && b < a) std::swap(a, b);
  }
  // Identities that keep the tape short.
  if (op == Op::mul_c && imm == 1.0) return a;
  if (op == Op::add_c && imm == 0.0) return a;
  if (op == Op::mul_c && imm == -1.0) return emit(Op::neg, a, 0, 0.0);
  const Key key{op, a, b, std::bit_cast<std::uint64_t>(imm)};
  if (auto it = numbering_.find(key); it != numbering_.end()) return it->second;
  const auto id = static_cast<std::int32_t>(code_.size());
  code_.push_back(Instr{op, a, b, 0, imm});
  numbering_.emplace(key, id);
  return id;
}

std::int32_t Tape::power(std::int32_t base, long n) {
  if (n == 0) return constant(1.0);
  if (n < 0) return emit(Op::div, constant(1.0), power(base, -n), 0.0);
  if (n == 1) return base;
  if (n == 2) return emit(Op::square, base, 0, 0.0);
  const std::int32_t half = power(base, n / 2);
  const std::int32_t sq = emit(Op::square, half, 0, 0.0);
  return n % 2 == 0 ? sq : emit(Op::mul, sq, base, 0.0);
}

std::int32_t Tape::compile(const ex& e, const InputMap& inputs) {
  if (auto it = memo_.find(e); it != memo_.end()) return it->second;
  // The budget every 4096 new subexpressions (one clock read per 4096 nodes: no measurable cost).
  if (deadline_ != nullptr && (++compiled_ & 4095U) == 0) deadline_->check(*where_);
  std::int32_t id = 0;
  if (is_a<GiNaC::numeric>(e) || is_a<GiNaC::constant>(e)) {
    id = constant(to_double(e));
  } else if (is_a<GiNaC::symbol>(e)) {
    auto it = inputs.find(e);
    if (it == inputs.end()) {
      std::ostringstream os;
      os << "unknown symbol '" << e << "' (not a coordinate, velocity, t or parameter)";
      throw Error(os.str());
    }
    const TapeInput in = it->second;
    const Op op = in.source == TapeInput::Source::time ? Op::time
                  : in.source == TapeInput::Source::q  ? Op::q
                                                       : Op::qd;
    id = emit(op, in.index, 0, 0.0);
  } else if (is_a<GiNaC::add>(e)) {
    // Σ terms: numeric coefficients become mul_c, a coefficient −1 a subtraction.
    // The terms in a structural order, not GiNaC's (address-seeded) one: the sum's rounding is the
    // same in every process.
    std::int32_t acc = -1;
    double offset = 0.0;
    for (const ex& term : order_->sorted_operands(e)) {
      if (is_a<GiNaC::numeric>(term)) {
        offset += to_double(term);
        continue;
      }
      double c = 1.0;
      ex rest = term;
      if (is_a<GiNaC::mul>(term)) {
        const ex last = term.op(term.nops() - 1);
        if (is_a<GiNaC::numeric>(last)) {
          c = to_double(last);
          rest = term / last;
        }
      }
      const std::int32_t r = compile(rest, inputs);
      if (acc < 0) {
        acc = emit(Op::mul_c, r, 0, c);
      } else if (c == -1.0) {
        acc = emit(Op::sub, acc, r, 0.0);
      } else {
        acc = emit(Op::add, acc, emit(Op::mul_c, r, 0, c), 0.0);
      }
    }
    id = acc < 0 ? constant(offset) : emit(Op::add_c, acc, 0, offset);
  } else if (is_a<GiNaC::mul>(e)) {
    double c = 1.0;
    std::int32_t num = -1, den = -1;
    for (const ex& f : order_->sorted_operands(e)) {  // structural order, as for sums
      if (is_a<GiNaC::numeric>(f)) {
        c *= to_double(f);
        continue;
      }
      bool denominator = false;
      std::int32_t v = 0;
      if (is_a<GiNaC::power>(f) && is_a<GiNaC::numeric>(f.op(1)) &&
          ex_to<GiNaC::numeric>(f.op(1)).is_negative()) {
        denominator = true;
        v = compile(GiNaC::pow(f.op(0), -f.op(1)), inputs);
      } else {
        v = compile(f, inputs);
      }
      std::int32_t& acc = denominator ? den : num;
      acc = acc < 0 ? v : emit(Op::mul, acc, v, 0.0);
    }
    if (num < 0) num = constant(1.0);
    if (den >= 0) num = emit(Op::div, num, den, 0.0);
    id = emit(Op::mul_c, num, 0, c);
  } else if (is_a<GiNaC::power>(e)) {
    const ex base = e.op(0), expo = e.op(1);
    const std::int32_t b = compile(base, inputs);
    // Compare as a numeric before to_long(): to_long() wraps exponents beyond 2^63 (2^65 + 1 → 1).
    if (is_a<GiNaC::numeric>(expo) && ex_to<GiNaC::numeric>(expo).is_integer() &&
        GiNaC::abs(ex_to<GiNaC::numeric>(expo)) <= 64) {
      id = power(b, ex_to<GiNaC::numeric>(expo).to_long());
    } else if (expo.is_equal(GiNaC::numeric(1, 2))) {
      id = emit(Op::sqrt, b, 0, 0.0);
    } else if (expo.is_equal(GiNaC::numeric(-1, 2))) {
      id = emit(Op::div, constant(1.0), emit(Op::sqrt, b, 0, 0.0), 0.0);
    } else {
      id = emit(Op::pow, b, compile(expo, inputs), 0.0);
    }
  } else if (is_a<GiNaC::function>(e)) {
    const std::string name = ex_to<GiNaC::function>(e).get_name();
    static const std::map<std::string, Op> unary = {
        {"sin", Op::sin},   {"cos", Op::cos},   {"tan", Op::tan},   {"asin", Op::asin},
        {"acos", Op::acos}, {"atan", Op::atan}, {"exp", Op::exp},   {"log", Op::log},
        {"sinh", Op::sinh}, {"cosh", Op::cosh}, {"tanh", Op::tanh}, {"abs", Op::abs}};
    if (auto it = unary.find(name); it != unary.end() && e.nops() == 1) {
      id = emit(it->second, compile(e.op(0), inputs), 0, 0.0);
    } else if (name == "ukdyn_spline" && e.nops() == 3) {
      const auto order = static_cast<std::size_t>(to_double(e.op(1)));
      const auto spline = spline_of(e.op(0));  // the tape shares ownership of the spline
      std::size_t local = 0;
      while (local < splines_.size() && splines_[local] != spline) ++local;
      if (local == splines_.size()) splines_.push_back(spline);
      const std::int32_t arg = compile(e.op(2), inputs);
      id = order > 3 ? constant(0.0)
                     : emit(Op::spline, arg, 0, static_cast<double>(local * 4 + order));
    } else if (name == "atan2" && e.nops() == 2) {
      id = emit(Op::atan2, compile(e.op(0), inputs), compile(e.op(1), inputs), 0.0);
    } else {
      throw Error("function '" + name + "' cannot be compiled");
    }
  } else {
    std::ostringstream os;
    os << "cannot compile expression '" << e << "'";
    throw Error(os.str());
  }
  memo_.emplace(e, id);
  return id;
}

namespace {

// Bitwise field-by-field equality of the tape's records (no padding bytes compared).
bool same_bits(double a, double b) {
  return std::bit_cast<std::uint64_t>(a) == std::bit_cast<std::uint64_t>(b);
}

}  // namespace

bool Tape::same_program(const Tape& o) const {
  auto same = [](const auto& x, const auto& y, auto eq) {
    return x.size() == y.size() && std::equal(x.begin(), x.end(), y.begin(), eq);
  };
  auto instr = [](const Instr& x, const Instr& y) {
    return x.op == y.op && x.a == y.a && x.b == y.b && x.c == y.c && same_bits(x.imm, y.imm);
  };
  auto load = [](const Load& x, const Load& y) {
    return x.dst == y.dst && x.index == y.index && same_bits(x.value, y.value);
  };
  auto exec = [](const Exec& x, const Exec& y) {
    return x.op == y.op && x.a == y.a && x.b == y.b && x.c == y.c && x.dst == y.dst &&
           same_bits(x.imm, y.imm);
  };
  return same(code_, o.code_, instr) && same(exec_, o.exec_, exec) &&
         same(constants_, o.constants_, load) && same(q_loads_, o.q_loads_, load) &&
         same(qd_loads_, o.qd_loads_, load) && same(time_loads_, o.time_loads_, load) &&
         out_ == o.out_ && splines_ == o.splines_;
}

std::uint64_t Tape::fingerprint() const {
  detail::Fnv1a64 h;
  auto add = [&h](std::uint64_t v) {
    for (int i = 0; i < 8; ++i) h.add(static_cast<unsigned char>(v >> (8 * i)));
  };
  add(code_.size());
  add(out_.size());
  for (const Instr& I : code_) {
    add(static_cast<std::uint64_t>(I.op) ^ (static_cast<std::uint64_t>(I.a) << 8) ^
        (static_cast<std::uint64_t>(static_cast<std::uint32_t>(I.b)) << 32));
    add(std::bit_cast<std::uint64_t>(I.imm));
  }
  for (const std::int32_t o : out_) add(static_cast<std::uint64_t>(o));
  return h.value();
}

std::shared_ptr<const Tape> TapePool::share(Tape&& tape) {
  const std::uint64_t key = tape.fingerprint();
  for (auto [it, end] = tapes_.equal_range(key); it != end; ++it) {
    if (it->second->same_program(tape)) {
      ++reused_;
      return it->second;
    }
  }
  auto shared = std::make_shared<const Tape>(std::move(tape));
  tapes_.emplace(key, shared);
  return shared;
}

InputMap coordinate_inputs(SymbolTable& table, const std::vector<std::string>& coordinates,
                           InputSet set) {
  InputMap in;
  for (std::size_t i = 0; i < coordinates.size(); ++i) {
    const std::string& c = coordinates[i];
    if (set == InputSet::q_interned && !table.has_coordinate(c)) continue;
    const auto index = static_cast<std::int32_t>(i);
    in[coordinate_symbol(table, c)] = {TapeInput::Source::q, index};
    if (set == InputSet::q_qd_time) in[velocity_symbol(table, c)] = {TapeInput::Source::qd, index};
  }
  if (set == InputSet::q_qd_time) in[time_symbol(table)] = {TapeInput::Source::time, 0};
  return in;
}

std::size_t tape_work(const std::vector<ex>& outputs, std::size_t limit, const std::string& where,
                      std::size_t done) {
  // Looked up only (never iterated): GiNaC's address-seeded hash places the entries, it does not
  // change the count.
  std::unordered_set<ex, std::hash<ex>, GiNaC::ex_is_equal> seen;
  std::vector<ex> pending(outputs.rbegin(), outputs.rend());
  std::size_t work = done;
  while (!pending.empty()) {
    const ex e = pending.back();
    pending.pop_back();
    if (++work > limit) {
      std::ostringstream os;
      os << "compiling the tapes would take more than " << limit << " operand visits (stopped at "
         << where
         << "; counted over their distinct subexpressions before any is compiled): write the "
            "positions (or constraint rows) with fewer terms or split the subsystem";
      throw DerivationTimeout(os.str());
    }
    if (e.nops() == 0 || !seen.insert(e).second) continue;
    for (std::size_t i = e.nops(); i-- > 0;) pending.push_back(e.op(i));
  }
  return work;
}

Tape::Tape(const std::vector<ex>& outputs, const InputMap& inputs) { build(outputs, inputs); }

Tape::Tape(const std::vector<ex>& outputs, const InputMap& inputs, const Deadline& deadline,
           const std::string& where) {
  deadline_ = &deadline;
  where_ = &where;
  build(outputs, inputs);
  deadline.check(where);
}

void Tape::build(const std::vector<ex>& outputs, const InputMap& inputs) {
  out_.reserve(outputs.size());
  order_ = std::make_shared<StructuralOrder>();
  for (const ex& e : outputs) {
    if (deadline_ != nullptr) deadline_->check(*where_);
    out_.push_back(compile(e, inputs));
  }
  numbering_.clear();
  memo_.clear();
  order_.reset();
  if (deadline_ != nullptr) deadline_->check(*where_);
  fuse_sin_cos();
  fuse_products();
  if (deadline_ != nullptr) deadline_->check(*where_);
  deadline_ = nullptr;  // only while compiling: a copy of the tape keeps no pointer to them
  where_ = nullptr;
  // What eval() runs: loads and constants by plain loops first (no dispatch), then the
  // instructions, without those folded away. Dispatching on every instruction, `fused` ones
  // included, cost about a third of a derived model's evaluation.
  for (std::size_t i = 0; i < code_.size(); ++i) {
    const Instr& I = code_[i];
    const auto dst = static_cast<std::int32_t>(i);
    switch (I.op) {
      case Op::fused:
        break;
      case Op::constant:
        constants_.push_back(Load{dst, 0, I.imm});
        break;
      case Op::q:
        q_loads_.push_back(Load{dst, I.a, 0.0});
        break;
      case Op::qd:
        qd_loads_.push_back(Load{dst, I.a, 0.0});
        break;
      case Op::time:
        time_loads_.push_back(Load{dst, 0, 0.0});
        break;
      default:
        exec_.push_back(Exec{I.op, I.a, I.b, I.c, dst, I.imm});
        break;
    }
  }
}

// Kinematics gives sin and cos of the same angle everywhere; one sincos costs about as much as one
// of the two calls. Each pair sin(x), cos(x) of the tape (common subexpressions are already
// shared, so there is at most one of each per x) becomes: the first of the two computes both and
// writes the other's slot, the second is skipped. Both slots get exactly the values the separate
// calls give (std::sin/std::cos and the sincos g++ emits for them are the same libm routines).
void Tape::fuse_sin_cos() {
  std::map<std::int32_t, std::pair<std::int32_t, std::int32_t>> by_arg;  // x → (sin, cos)
  for (std::size_t i = 0; i < code_.size(); ++i) {
    const Instr& I = code_[i];
    if (I.op != Op::sin && I.op != Op::cos) continue;
    auto [it, fresh] = by_arg.try_emplace(I.a, -1, -1);
    (I.op == Op::sin ? it->second.first : it->second.second) = static_cast<std::int32_t>(i);
  }
  for (const auto& [x, sc] : by_arg) {
    const auto [si, ci] = sc;
    if (si < 0 || ci < 0) continue;
    const std::int32_t first = std::min(si, ci), second = std::max(si, ci);
    Instr& F = code_[static_cast<std::size_t>(first)];
    F.op = first == si ? Op::sin_cos : Op::cos_sin;
    F.b = second;
    code_[static_cast<std::size_t>(second)].op = Op::fused;
  }
}

std::size_t Tape::operations() const {
  std::size_t k = 0;
  for (const Instr& I : code_) {
    if (I.op == Op::sin_cos || I.op == Op::cos_sin || I.op == Op::add_mul || I.op == Op::sub_mul ||
        I.op == Op::add_mul_c || I.op == Op::sub_mul_c || I.op == Op::mul_c_mul ||
        I.op == Op::mul_mul_c) {
      k += 2;  // still two operations, as before fusing
    } else if (I.op != Op::constant && I.op != Op::time && I.op != Op::q && I.op != Op::qd &&
               I.op != Op::fused) {
      ++k;
    }
  }
  return k;
}

// An interpreted tape pays a dispatch per instruction, about as much as the arithmetic; sums of
// products are most of a derived model. A product (mul or mul_c) whose only use is an add, sub or
// mul becomes part of that instruction and is skipped. The fused instruction evaluates the same
// operations in the same order (the product first), so the values do not change.
void Tape::fuse_products() {
  std::vector<int> uses(code_.size(), 0);
  for (const Instr& I : code_) {
    switch (I.op) {
      case Op::constant:
      case Op::time:
      case Op::q:
      case Op::qd:
      case Op::fused:
        break;
      case Op::sin_cos:
      case Op::cos_sin:  // b is the slot it writes, not an operand
        ++uses[static_cast<std::size_t>(I.a)];
        break;
      default:
        ++uses[static_cast<std::size_t>(I.a)];
        if (is_binary(I.op)) ++uses[static_cast<std::size_t>(I.b)];
        break;
    }
  }
  for (const std::int32_t o : out_) ++uses[static_cast<std::size_t>(o)];
  auto single = [&](std::int32_t k, Op op) {
    return code_[static_cast<std::size_t>(k)].op == op && uses[static_cast<std::size_t>(k)] == 1;
  };
  for (Instr& I : code_) {
    const std::int32_t x = I.a, y = I.b;
    if (I.op == Op::add || I.op == Op::sub) {
      const bool add = I.op == Op::add;
      // The product as the second operand (or, for add, the first: add is commutative).
      std::int32_t prod = -1, other = x;
      if (single(y, Op::mul) || single(y, Op::mul_c)) {
        prod = y;
      } else if (add && (single(x, Op::mul) || single(x, Op::mul_c))) {
        prod = x;
        other = y;
      }
      if (prod < 0) continue;
      Instr& P = code_[static_cast<std::size_t>(prod)];
      if (P.op == Op::mul) {
        I = Instr{add ? Op::add_mul : Op::sub_mul, other, P.a, P.b, 0.0};
      } else {
        I = Instr{add ? Op::add_mul_c : Op::sub_mul_c, other, P.a, 0, P.imm};
      }
      P.op = Op::fused;
    } else if (I.op == Op::mul && (single(x, Op::mul_c) || single(y, Op::mul_c))) {
      const bool first = single(x, Op::mul_c);
      Instr& P = code_[static_cast<std::size_t>(first ? x : y)];
      I = Instr{Op::mul_c_mul, P.a, first ? y : x, 0, P.imm};
      P.op = Op::fused;
    } else if (I.op == Op::mul_c && single(x, Op::mul)) {
      Instr& P = code_[static_cast<std::size_t>(x)];
      I = Instr{Op::mul_mul_c, P.a, P.b, 0, I.imm};
      P.op = Op::fused;
    }
  }
}

std::size_t Tape::executed_instructions() const {
  return code_.size() -
         static_cast<std::size_t>(std::count_if(code_.begin(), code_.end(),
                                                [](const Instr& I) { return I.op == Op::fused; }));
}

std::size_t Tape::sincos_pairs() const {
  return static_cast<std::size_t>(std::count_if(code_.begin(), code_.end(), [](const Instr& I) {
    return I.op == Op::sin_cos || I.op == Op::cos_sin;
  }));
}

void Tape::eval(double t, const double* q, const double* qd, double* out) const {
  if (code_.size() <= kStackWork) {
    double work[kStackWork];
    eval(t, q, qd, out, work);
    return;
  }
  std::vector<double> work(code_.size());
  eval(t, q, qd, out, work.data());
}

void Tape::eval(double t, const double* q, const double* qd, double* out, double* work) const {
  double* w = work;
  for (const Load& L : constants_) w[L.dst] = L.value;
  for (const Load& L : time_loads_) w[L.dst] = t;
  for (const Load& L : q_loads_) w[L.dst] = q[L.index];
  for (const Load& L : qd_loads_) w[L.dst] = qd[L.index];
  for (const Exec& I : exec_) {
    double v;
    switch (I.op) {
      case Op::constant:  // loaded above; none of these four is in exec_
      case Op::time:
      case Op::q:
      case Op::qd:
      case Op::fused:
        continue;
      case Op::add:
        v = w[I.a] + w[I.b];
        break;
      case Op::sub:
        v = w[I.a] - w[I.b];
        break;
      case Op::mul:
        v = w[I.a] * w[I.b];
        break;
      case Op::mul_c:
        v = w[I.a] * I.imm;
        break;
      case Op::add_c:
        v = w[I.a] + I.imm;
        break;
      case Op::neg:
        v = -w[I.a];
        break;
      case Op::square:
        v = w[I.a] * w[I.a];
        break;
      case Op::spline: {
        const auto k = static_cast<std::size_t>(I.imm);
        v = splines_[k / 4]->eval(w[I.a], static_cast<int>(k % 4));
        break;
      }
      case Op::sin_cos:
      case Op::cos_sin: {
        const double x = w[I.a];
        const double s = std::sin(x), c = std::cos(x);  // one sincos call
        v = I.op == Op::sin_cos ? s : c;
        w[I.b] = I.op == Op::sin_cos ? c : s;
        break;
      }
      case Op::add_mul:
        v = w[I.a] + w[I.b] * w[I.c];
        break;
      case Op::sub_mul:
        v = w[I.a] - w[I.b] * w[I.c];
        break;
      case Op::add_mul_c:
        v = w[I.a] + w[I.b] * I.imm;
        break;
      case Op::sub_mul_c:
        v = w[I.a] - w[I.b] * I.imm;
        break;
      case Op::mul_c_mul:
        v = (w[I.a] * I.imm) * w[I.b];
        break;
      case Op::mul_mul_c:
        v = (w[I.a] * w[I.b]) * I.imm;
        break;
      default:
        v = apply(I.op, w[I.a], w[I.b], I.imm);
        break;
    }
    w[I.dst] = v;
  }
  for (std::size_t k = 0; k < out_.size(); ++k) out[k] = w[out_[k]];
}

// ------------------------------------------------------------------------------- forward mode
//
// Tangent-linear evaluation [Griewank2008, ch. 3]: every slot w carries, next to its value, the
// derivatives dw of its value along K directions (dw[slot·K + k]); each instruction's tangents are
// the chain rule of its operation applied to its operands' tangents. The values are computed by the
// same expressions as eval(), so they are bitwise eval()'s.

namespace {

// The lane loops: N = 1 a fixed single direction, N = 0 the run-time K. The same expression per
// lane for every K, so direction k of a K-direction run is bitwise the single-direction run.
template <std::size_t N>
inline std::size_t lanes(std::size_t K) {
  return N != 0 ? N : K;
}

// dv = p · da.
template <std::size_t N>
inline void scale(double* __restrict dv, const double* __restrict da, double p, std::size_t K) {
  for (std::size_t k = 0; k < lanes<N>(K); ++k) dv[k] = p * da[k];
}

// dv = p · da, and 0 where da = 0 (p may be infinite or NaN: sqrt, log, asin, acos at the edge).
template <std::size_t N>
inline void scale_nonzero(double* __restrict dv, const double* __restrict da, double p,
                          std::size_t K) {
  for (std::size_t k = 0; k < lanes<N>(K); ++k) dv[k] = da[k] == 0.0 ? 0.0 : p * da[k];
}

// dv = p · da + r · db.
template <std::size_t N>
inline void combine(double* __restrict dv, const double* __restrict da, double p,
                    const double* __restrict db, double r, std::size_t K) {
  for (std::size_t k = 0; k < lanes<N>(K); ++k) dv[k] = p * da[k] + r * db[k];
}

// The value of a function op at x (and y, its second operand if binary) and, into dv, its tangents
// from the operands' da (and db).
template <std::size_t N>
double function_tangent(Tape::Op op, double x, double y, const double* da, const double* db,
                        double* dv, std::size_t K) {
  const std::size_t L = lanes<N>(K);
  double v;
  switch (op) {
    case Tape::Op::pow: {
      // d(x^y) = y x^(y−1) dx + x^y ln(x) dy; a zero dy drops the second term (x ≤ 0 allowed
      // then), a zero dx the first (x^(y−1) infinite at 0).
      v = std::pow(x, y);
      const double px = y * std::pow(x, y - 1.0);
      const double py = v * std::log(x);
      for (std::size_t k = 0; k < L; ++k) {
        const double tx = da[k] == 0.0 ? 0.0 : px * da[k];
        dv[k] = db[k] == 0.0 ? tx : tx + py * db[k];
      }
      return v;
    }
    case Tape::Op::sqrt:
      v = std::sqrt(x);
      scale_nonzero<N>(dv, da, 0.5 / v, K);
      return v;
    case Tape::Op::sin:
      v = std::sin(x);
      scale<N>(dv, da, std::cos(x), K);
      return v;
    case Tape::Op::cos:
      v = std::cos(x);
      scale<N>(dv, da, -std::sin(x), K);
      return v;
    case Tape::Op::tan:
      v = std::tan(x);
      scale<N>(dv, da, 1.0 + v * v, K);
      return v;
    case Tape::Op::asin:
      v = std::asin(x);
      scale_nonzero<N>(dv, da, 1.0 / std::sqrt(1.0 - x * x), K);
      return v;
    case Tape::Op::acos:
      v = std::acos(x);
      scale_nonzero<N>(dv, da, -1.0 / std::sqrt(1.0 - x * x), K);
      return v;
    case Tape::Op::atan:
      v = std::atan(x);
      scale<N>(dv, da, 1.0 / (1.0 + x * x), K);
      return v;
    case Tape::Op::atan2: {
      const double r2 = x * x + y * y;  // atan2(x, y): x the ordinate
      v = std::atan2(x, y);
      combine<N>(dv, da, y / r2, db, -x / r2, K);
      return v;
    }
    case Tape::Op::exp:
      v = std::exp(x);
      scale<N>(dv, da, v, K);
      return v;
    case Tape::Op::log:
      v = std::log(x);
      scale_nonzero<N>(dv, da, 1.0 / x, K);
      return v;
    case Tape::Op::sinh:
      v = std::sinh(x);
      scale<N>(dv, da, std::cosh(x), K);
      return v;
    case Tape::Op::cosh:
      v = std::cosh(x);
      scale<N>(dv, da, std::sinh(x), K);
      return v;
    case Tape::Op::tanh:
      v = std::tanh(x);
      scale<N>(dv, da, 1.0 - v * v, K);
      return v;
    case Tape::Op::abs:
      v = std::abs(x);
      scale<N>(dv, da, x > 0.0 ? 1.0 : x < 0.0 ? -1.0 : 0.0, K);
      return v;
    default:
      return 0.0;  // not a function op: tangent_step handles it
  }
}

}  // namespace

template <std::size_t N>
void Tape::tangent_step(const Exec& I, std::size_t K, double* w, double* dw) const {
  const std::size_t L = lanes<N>(K);
  const double x = w[I.a];
  const double* da = dw + static_cast<std::size_t>(I.a) * L;
  const double* db = dw + static_cast<std::size_t>(I.b) * L;  // b: an operand of binary ops only
  double* dv = dw + static_cast<std::size_t>(I.dst) * L;
  double v;
  switch (I.op) {
    case Op::add:
      v = x + w[I.b];
      for (std::size_t k = 0; k < L; ++k) dv[k] = da[k] + db[k];
      break;
    case Op::sub:
      v = x - w[I.b];
      for (std::size_t k = 0; k < L; ++k) dv[k] = da[k] - db[k];
      break;
    case Op::mul:
      v = x * w[I.b];
      combine<N>(dv, da, w[I.b], db, x, K);
      break;
    case Op::div: {
      const double y = w[I.b];
      v = x / y;
      for (std::size_t k = 0; k < L; ++k) dv[k] = (da[k] - v * db[k]) / y;
      break;
    }
    case Op::neg:
      v = -x;
      for (std::size_t k = 0; k < L; ++k) dv[k] = -da[k];
      break;
    case Op::add_c:
      v = x + I.imm;
      for (std::size_t k = 0; k < L; ++k) dv[k] = da[k];
      break;
    case Op::mul_c: {
      const double c = I.imm;
      v = x * c;
      for (std::size_t k = 0; k < L; ++k) dv[k] = da[k] * c;
      break;
    }
    case Op::square:
      v = x * x;
      scale<N>(dv, da, 2.0 * x, K);
      break;
    case Op::sin_cos:
    case Op::cos_sin: {
      const double s = std::sin(x), c = std::cos(x);  // one sincos call
      const bool sin_first = I.op == Op::sin_cos;
      v = sin_first ? s : c;
      w[I.b] = sin_first ? c : s;
      scale<N>(dv, da, sin_first ? c : -s, K);
      scale<N>(dw + static_cast<std::size_t>(I.b) * L, da, sin_first ? -s : c, K);
      break;
    }
    case Op::spline: {
      const auto s = static_cast<std::size_t>(I.imm);
      const CubicSpline& S = *splines_[s / 4];
      const int d = static_cast<int>(s % 4);
      v = S.eval(x, d);
      scale<N>(dv, da, d < 3 ? S.eval(x, d + 1) : 0.0, K);  // a cubic: the 4th derivative is 0
      break;
    }
    case Op::add_mul:
    case Op::sub_mul: {
      const double y = w[I.b], z = w[I.c];
      const double* dc = dw + static_cast<std::size_t>(I.c) * L;
      const bool add = I.op == Op::add_mul;
      v = add ? x + y * z : x - y * z;
      for (std::size_t k = 0; k < L; ++k) {
        const double dp = db[k] * z + y * dc[k];
        dv[k] = add ? da[k] + dp : da[k] - dp;
      }
      break;
    }
    case Op::add_mul_c:
    case Op::sub_mul_c: {
      const double c = I.imm;
      const bool add = I.op == Op::add_mul_c;
      v = add ? x + w[I.b] * c : x - w[I.b] * c;
      for (std::size_t k = 0; k < L; ++k) dv[k] = add ? da[k] + db[k] * c : da[k] - db[k] * c;
      break;
    }
    case Op::mul_c_mul: {
      const double c = I.imm, xc = x * c, y = w[I.b];
      v = xc * y;
      for (std::size_t k = 0; k < L; ++k) dv[k] = (da[k] * c) * y + xc * db[k];
      break;
    }
    case Op::mul_mul_c: {
      const double c = I.imm, y = w[I.b];
      v = (x * y) * c;
      for (std::size_t k = 0; k < L; ++k) dv[k] = (da[k] * y + x * db[k]) * c;
      break;
    }
    case Op::constant:  // loaded before the instructions; none of these is in exec_
    case Op::time:
    case Op::q:
    case Op::qd:
    case Op::fused:
      return;
    default:
      v = function_tangent<N>(I.op, x, w[I.b], da, db, dv, K);
      break;
  }
  w[I.dst] = v;
}

template <std::size_t N>
void Tape::run_tangents(std::size_t K, double t, const double* q, const double* qd,
                        const double* dt, const double* dq, std::size_t n_q, const double* dqd,
                        std::size_t n_qd, double* out, double* dout, double* work,
                        double* dwork) const {
  const std::size_t L = lanes<N>(K);
  double* w = work;
  double* dw = dwork;
  auto lane = [&](std::int32_t slot) { return dw + static_cast<std::size_t>(slot) * L; };
  for (const Load& ld : constants_) {
    w[ld.dst] = ld.value;
    std::fill_n(lane(ld.dst), L, 0.0);
  }
  for (const Load& ld : time_loads_) {
    w[ld.dst] = t;
    double* d = lane(ld.dst);
    for (std::size_t k = 0; k < L; ++k) d[k] = dt != nullptr ? dt[k] : 0.0;
  }
  for (const Load& ld : q_loads_) {
    w[ld.dst] = q[ld.index];
    double* d = lane(ld.dst);
    const auto j = static_cast<std::size_t>(ld.index);
    for (std::size_t k = 0; k < L; ++k) d[k] = dq != nullptr ? dq[j + n_q * k] : 0.0;
  }
  for (const Load& ld : qd_loads_) {
    w[ld.dst] = qd[ld.index];
    double* d = lane(ld.dst);
    const auto j = static_cast<std::size_t>(ld.index);
    for (std::size_t k = 0; k < L; ++k) d[k] = dqd != nullptr ? dqd[j + n_qd * k] : 0.0;
  }
  for (const Exec& I : exec_) tangent_step<N>(I, K, w, dw);
  const std::size_t m = out_.size();
  for (std::size_t i = 0; i < m; ++i) {
    out[i] = w[out_[i]];
    const double* d = lane(out_[i]);
    for (std::size_t k = 0; k < L; ++k) dout[i + m * k] = d[k];
  }
}

std::vector<Index> Tape::inputs_read(TapeInput::Source source) const {
  std::vector<Index> read;
  if (source == TapeInput::Source::time) return read;
  for (const Load& ld : source == TapeInput::Source::q ? q_loads_ : qd_loads_)
    read.push_back(ld.index);
  std::sort(read.begin(), read.end());
  read.erase(std::unique(read.begin(), read.end()), read.end());
  return read;
}

void Tape::eval_tangent(double t, const double* q, const double* qd, double dt, const double* dq,
                        const double* dqd, double* out, double* dout, double* work,
                        double* dwork) const {
  run_tangents<1>(1, t, q, qd, &dt, dq, 0, dqd, 0, out, dout, work, dwork);
}

void Tape::eval_tangents(std::size_t K, double t, const double* q, const double* qd,
                         const double* dt, const double* dq, std::size_t n_q, const double* dqd,
                         std::size_t n_qd, double* out, double* dout, double* work,
                         double* dwork) const {
  run_tangents<0>(K, t, q, qd, dt, dq, n_q, dqd, n_qd, out, dout, work, dwork);
}

}  // namespace ukdyn::symbolic
