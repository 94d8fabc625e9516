// A compiled, allocation-free evaluator of a list of GiNaC expressions: a flat instruction tape in
// static single assignment form (every instruction writes its own slot). Common subexpressions are
// shared by value numbering (hash-consing of instructions), so an identical subtree, or an
// identical prefix of a product or sum, is computed once. Inputs are read directly from t, q and q̇.
#pragma once

#include <ginac/ginac.h>

#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "ukdyn/core/types.hpp"

namespace ukdyn::symbolic {

class CubicSpline;
class Deadline;
class StructuralOrder;

/// Where a symbol's value comes from when the tape runs.
struct TapeInput {
  enum class Source : std::uint8_t { time, q, qd };
  Source source = Source::q;
  std::int32_t index = 0;
};

/// symbol → input. Symbols not in the map are errors at compile time.
using InputMap = std::map<GiNaC::ex, TapeInput, GiNaC::ex_is_less>;

class Tape {
 public:
  enum class Op : std::uint8_t {
    constant,
    time,
    q,
    qd,
    add,
    sub,
    mul,
    div,
    neg,
    add_c,
    mul_c,
    square,
    pow,
    sqrt,
    sin,
    cos,
    tan,
    asin,
    acos,
    atan,
    atan2,
    exp,
    log,
    sinh,
    cosh,
    tanh,
    abs,
    spline,   ///< splines_[imm / 4]->eval(a, imm % 4) (ukdyn/symbolic/spline.hpp)
    sin_cos,  ///< a sin whose argument also has a cos: w = sin(a), and w[b] = cos(a)
    cos_sin,  ///< a cos whose argument also has a sin: w = cos(a), and w[b] = sin(a)
    fused,    ///< nothing to do: written by its sin_cos/cos_sin pair, or folded into its one user
    // Superinstructions: an add, sub or mul together with the product its operand held (that
    // product had no other use). Same operations in the same order as the two instructions.
    add_mul,    ///< w[a] + w[b]·w[c]
    sub_mul,    ///< w[a] − w[b]·w[c]
    add_mul_c,  ///< w[a] + w[b]·imm
    sub_mul_c,  ///< w[a] − w[b]·imm
    mul_c_mul,  ///< (w[a]·imm)·w[b]
    mul_mul_c   ///< (w[a]·w[b])·imm
  };
  struct Instr {
    Op op;
    std::int32_t a;
    std::int32_t b;
    std::int32_t c = 0;  ///< third operand of add_mul / sub_mul
    double imm;
  };

  Tape() = default;
  /// Compiles `outputs` (numbers only: every parameter already substituted). Throws ukdyn::Error on
  /// a symbol missing from `inputs` or an unsupported function.
  Tape(const std::vector<GiNaC::ex>& outputs, const InputMap& inputs);
  /// The same within `deadline` (expression.hpp): checked every few thousand subexpressions
  /// compiled and between the passes, so that compiling a derivation's results counts against the
  /// derivation's budget; throws DerivationTimeout naming `where` once it is spent.
  Tape(const std::vector<GiNaC::ex>& outputs, const InputMap& inputs, const Deadline& deadline,
       const std::string& where);

  [[nodiscard]] std::size_t outputs() const { return out_.size(); }
  [[nodiscard]] std::size_t instructions() const { return code_.size(); }
  /// Number of arithmetic/function instructions (not loads or constants).
  [[nodiscard]] std::size_t operations() const;
  /// Number of sin/cos pairs of one argument evaluated by one sincos.
  [[nodiscard]] std::size_t sincos_pairs() const;
  /// Instructions eval() executes (instructions() less those folded into a pair or a user).
  [[nodiscard]] std::size_t executed_instructions() const;

  /// Whether `other` runs the same program: the same instructions, loads, constants (bitwise),
  /// outputs and splines (the same objects). Two such tapes give bitwise the same outputs for every
  /// input, so one of them can stand for both (TapePool).
  [[nodiscard]] bool same_program(const Tape& other) const;
  /// A hash of the program: equal for tapes with same_program().
  [[nodiscard]] std::uint64_t fingerprint() const;

  /// The indices of `source` (q or q̇) that the tape reads, each once, ascending: the directions
  /// along which its outputs can have a tangent (along any other their tangents are zero).
  [[nodiscard]] std::vector<Index> inputs_read(TapeInput::Source source) const;

  /// Doubles of work buffer eval() needs (one per instruction slot).
  [[nodiscard]] std::size_t work_size() const { return code_.size(); }
  /// Evaluates every output into out[0..outputs()), with the caller's work buffer `work` of
  /// work_size() doubles (a ForwardData slot, say). Allocation-free. q and qd may be null if the
  /// tape reads none. The tape itself is constant: one tape may run on many threads, each with its
  /// own work buffer.
  void eval(double t, const double* q, const double* qd, double* out, double* work) const;
  /// The same with a work buffer of its own: on the stack up to kStackWork doubles, else on the
  /// heap (allocates: not for the integration hot path of a large model).
  void eval(double t, const double* q, const double* qd, double* out) const;
  static constexpr std::size_t kStackWork = 2048;

  /// Forward mode: the outputs and their directional derivatives along (dt, dq, dqd): out[i] and
  /// dout[i] = Σ ∂out_i/∂t dt + ∂out_i/∂q_j dq_j + ∂out_i/∂qd_j dqd_j. work and dwork: work_size()
  /// doubles each. Allocation-free; exact (the derivative rules of each op, no differences;
  /// docs/architecture.md, "Tangents"). out is bitwise what eval() gives. dq or dqd null: zero
  /// tangents of q or q̇. A zero tangent stays zero through an op whose derivative is infinite
  /// there (sqrt, log, asin, acos, pow at 0); abs at 0 has derivative 0.
  void eval_tangent(double t, const double* q, const double* qd, double dt, const double* dq,
                    const double* dqd, double* out, double* dout, double* work,
                    double* dwork) const;
  /// The same along K directions at once (the values computed once, K tangents per slot).
  /// Directions column-major: dq is n_q×K (dq[j + n_q k]), dqd n_qd×K, dt K values (null: 0), dq
  /// or dqd null: 0; dout is outputs()×K (dout[i + outputs() k]). work: work_size() doubles, dwork
  /// work_size()·K. Direction k gives bitwise what eval_tangent() gives along it. Allocation-free.
  void eval_tangents(std::size_t K, double t, const double* q, const double* qd, const double* dt,
                     const double* dq, std::size_t n_q, const double* dqd, std::size_t n_qd,
                     double* out, double* dout, double* work, double* dwork) const;

 private:
  std::int32_t emit(Op op, std::int32_t a, std::int32_t b, double imm);
  void build(const std::vector<GiNaC::ex>& outputs, const InputMap& inputs);
  std::int32_t compile(const GiNaC::ex& e, const InputMap& inputs);
  std::int32_t constant(double v) { return emit(Op::constant, 0, 0, v); }
  std::int32_t power(std::int32_t base, long n);
  void fuse_sin_cos();
  void fuse_products();
  // Forward mode (tape.cpp): N = 1 for one direction, N = 0 for K given at run time.
  template <std::size_t N>
  void run_tangents(std::size_t K, double t, const double* q, const double* qd, const double* dt,
                    const double* dq, std::size_t n_q, const double* dqd, std::size_t n_qd,
                    double* out, double* dout, double* work, double* dwork) const;
  struct Exec;
  template <std::size_t N>
  void tangent_step(const Exec& I, std::size_t K, double* w, double* dw) const;

  std::vector<Instr> code_;
  /// Inputs and constants, written by plain loops before the instructions run.
  struct Load {
    std::int32_t dst;
    std::int32_t index;  ///< q / q̇ index (unused for constants and time)
    double value;        ///< the constant (unused for the others)
  };
  std::vector<Load> constants_, q_loads_, qd_loads_, time_loads_;
  /// What eval() runs: the instructions of code_ that are neither `fused` nor a load, with slots.
  struct Exec {
    Op op;
    std::int32_t a, b, c;
    std::int32_t dst;
    double imm;
  };
  std::vector<Exec> exec_;
  std::vector<std::int32_t> out_;
  std::vector<std::shared_ptr<const CubicSpline>> splines_;  // the splines the tape evaluates
  struct Key {
    Op op;
    std::int32_t a, b;
    std::uint64_t imm_bits;
    bool operator<(const Key& o) const;
  };
  std::map<Key, std::int32_t> numbering_;  // only used while compiling
  std::map<GiNaC::ex, std::int32_t, GiNaC::ex_is_less> memo_;
  // Operands of sums and products in a process-independent order (canonical.hpp); compiling only.
  std::shared_ptr<StructuralOrder> order_;
  // The budget while compiling (null: none, or compiled), and the subexpressions compiled so far.
  const Deadline* deadline_ = nullptr;
  const std::string* where_ = nullptr;
  std::size_t compiled_ = 0;
};

/// Identical tapes kept once: share() returns a tape with the same program already in the pool,
/// or adds this one. The instances of one robot (the same definitions and parameter values that
/// their M, C q̇ and G depend on) then evaluate one compiled tape over their own states and data
/// slots, which keeps the working set of N robots that of one (docs/performance.md, "N robots on
/// one load"). Caller-owned (a scenario loader's, say) and not thread-safe; the tapes it hands out
/// are constant and outlive it.
class TapePool {
 public:
  std::shared_ptr<const Tape> share(Tape&& tape);
  /// Distinct tapes in the pool, and share() calls answered with one already there.
  [[nodiscard]] std::size_t size() const { return tapes_.size(); }
  [[nodiscard]] std::size_t reused() const { return reused_; }

 private:
  std::multimap<std::uint64_t, std::shared_ptr<const Tape>> tapes_;
  std::size_t reused_ = 0;
};

}  // namespace ukdyn::symbolic
