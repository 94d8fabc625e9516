#include "ukdyn/symbolic/frame_constraints.hpp"

#include <cmath>
#include <sstream>

#include "symbolic/ex_helpers.hpp"
#include "symbolic/mat3.hpp"
#include "ukdyn/symbolic/expression.hpp"
#include "ukdyn/symbolic/tape_inputs.hpp"

namespace ukdyn::symbolic {

namespace {

using GiNaC::ex;

ex dot(const Vec3Ex& a, const Vec3Ex& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

Vec3Ex cross(const Vec3Ex& a, const Vec3Ex& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}

double number(const ex& e, const GiNaC::exmap& values, const std::string& what) {
  const ex v = e.subs(values).evalf();
  if (!GiNaC::is_a<GiNaC::numeric>(v) || !GiNaC::ex_to<GiNaC::numeric>(v).is_real())
    throw DefinitionError(what + " must be a constant, got " + str(e));
  return GiNaC::ex_to<GiNaC::numeric>(v).to_double();
}

// A constant nonzero vector scaled to unit length (exactly: by the square root of its norm²).
Vec3Ex unit(const Vec3Ex& a, const GiNaC::exmap& values, const std::string& what) {
  Vec3Ex v{a[0].subs(values), a[1].subs(values), a[2].subs(values)};
  const ex n2 = dot(v, v).expand();
  if (!(number(n2, values, what) > 0.0))
    throw DefinitionError(what + " must be a nonzero vector, got [" + str(a[0]) + ", " + str(a[1]) +
                          ", " + str(a[2]) + "]");
  if (n2.is_equal(1)) return v;
  const ex n = GiNaC::sqrt(n2);
  return {(v[0] / n).normal(), (v[1] / n).normal(), (v[2] / n).normal()};
}

// Two unit vectors n1, n2 with (u, n1, n2) orthonormal: n1 ∝ u × e_k for the world axis e_k of
// the smallest |u_k|, n2 = u × n1.
std::pair<Vec3Ex, Vec3Ex> perpendiculars(const Vec3Ex& u, const GiNaC::exmap& values) {
  std::size_t k = 0;
  double best = 2.0;
  for (std::size_t i = 0; i < 3; ++i) {
    const double c = std::abs(number(u[i], values, "the axis"));
    if (c < best - 1e-12) {
      best = c;
      k = i;
    }
  }
  Vec3Ex e{0, 0, 0};
  e[k] = 1;
  const Vec3Ex n1 = unit(cross(u, e), values, "the axis");
  Vec3Ex n2 = cross(u, n1);
  for (auto& c : n2) c = c.expand();
  return {n1, n2};
}

void need_rotation(const FramePose& p, const std::string& frame, const char* kind) {
  if (!p.has_rotation) {
    throw DefinitionError(std::string("a ") + kind + " needs the orientation of frame '" + frame +
                          "', but it has none (a body without `rotation`: use ball or distance, "
                          "or give the body a rotation)");
  }
}

}  // namespace

const char* to_string(FrameConstraintDef::Kind kind) {
  switch (kind) {
    case FrameConstraintDef::Kind::weld:
      return "weld";
    case FrameConstraintDef::Kind::ball:
      return "ball";
    case FrameConstraintDef::Kind::hinge:
      return "hinge";
    case FrameConstraintDef::Kind::level:
      return "level";
    case FrameConstraintDef::Kind::distance:
      return "distance";
  }
  return "?";
}

FramePose offset_frame(const FramePose& frame, const OriginDef& offset) {
  FramePose r = frame;
  const bool moves =
      !offset.xyz[0].is_zero() || !offset.xyz[1].is_zero() || !offset.xyz[2].is_zero();
  const bool turns =
      !offset.rpy[0].is_zero() || !offset.rpy[1].is_zero() || !offset.rpy[2].is_zero();
  if ((moves || turns) && !frame.has_rotation) {
    throw DefinitionError(
        "an offset needs the frame's orientation, but the frame has none (a body without "
        "`rotation`)");
  }
  if (moves) {
    const Vec3Ex d = mul(frame.rotation, offset.xyz);
    for (std::size_t k = 0; k < 3; ++k) r.position[k] = (frame.position[k] + d[k]).expand();
  }
  if (turns) {
    r.rotation = mul(frame.rotation, rpy_rotation(offset.rpy));
    for (auto& e : r.rotation) e = e.expand();
  }
  return r;
}

// ------------------------------------------------------------------------------ FrameTable

void FrameTable::add(const std::string& subsystem, const std::string& name, FramePose pose) {
  frames_[subsystem + "." + name] = std::move(pose);
}

void FrameTable::add_chain(const std::string& subsystem, const ChainModel& model,
                           const ChainDef* def) {
  const GiNaC::exmap values = model.def.parameter_values();
  auto subs = [&](FramePose p) {
    for (auto& e : p.position) e = e.subs(values);
    for (auto& e : p.rotation) e = e.subs(values);
    return p;
  };
  for (const auto& [link, pose] : model.links)
    add(subsystem, link, subs(FramePose{pose.position, pose.rotation, true}));
  std::map<std::string, std::string> point_link;
  if (def != nullptr) {
    for (const auto& p : def->points) point_link[p.name] = p.link;
  }
  for (const auto& [point, pos] : model.points) {
    if (frames_.count(subsystem + "." + point)) continue;  // a link's own origin
    FramePose f{pos, {1, 0, 0, 0, 1, 0, 0, 0, 1}, false};
    if (auto it = point_link.find(point); it != point_link.end()) {
      if (auto l = model.links.find(it->second); l != model.links.end()) {
        f.rotation = l->second.rotation;
        f.has_rotation = true;
      }
    }
    add(subsystem, point, subs(f));
  }
}

void FrameTable::add_bodies(const SubsystemDef& def) {
  const GiNaC::exmap values = def.parameter_values();
  for (const auto& b : def.bodies) {
    FramePose f;
    for (std::size_t k = 0; k < 3; ++k) f.position[k] = b.com[k].subs(values);
    f.has_rotation = b.rotation.has_value();
    if (b.rotation) {
      for (std::size_t k = 0; k < 9; ++k) f.rotation[k] = (*b.rotation)[k].subs(values);
    }
    add(def.name(), b.name, f);
  }
}

const FramePose& FrameTable::find(const std::string& ref) const {
  if (ref == "world") return world_;
  auto it = frames_.find(ref);
  if (it == frames_.end()) {
    std::string known;
    for (const auto& [k, v] : frames_) known += (known.empty() ? "" : ", ") + k;
    throw DefinitionError("no frame '" + ref + "' (known: world" + (known.empty() ? "" : ", ") +
                          known + ")");
  }
  return it->second;
}

std::vector<std::string> FrameTable::names() const {
  std::vector<std::string> r{"world"};
  for (const auto& [k, v] : frames_) r.push_back(k);
  return r;
}

// ------------------------------------------------------------------------------ rows

namespace {

std::vector<std::pair<std::string, ex>> rows_for(const FrameConstraintDef& f, const FramePose& a,
                                                 const FramePose& b, const GiNaC::exmap& values) {
  using K = FrameConstraintDef::Kind;
  std::vector<std::pair<std::string, ex>> rows;
  const std::string& p = f.name;
  auto position_rows = [&] {
    static const char* const kAxis[3] = {"x", "y", "z"};
    for (std::size_t k = 0; k < 3; ++k)
      rows.emplace_back(p + "_" + kAxis[k], a.position[k] - b.position[k]);
  };
  switch (f.kind) {
    case K::weld: {
      need_rotation(a, f.frame_a, "weld");
      need_rotation(b, f.frame_b, "weld");
      position_rows();
      // ½ vee(R_rel − R_relᵀ), R_rel = R_aᵀ R_b: sin θ · u (docs/frame-constraints.md).
      const Mat3Ex R = mul_tn(a.rotation, b.rotation);
      rows.emplace_back(p + "_rx", (R[7] - R[5]) / 2);
      rows.emplace_back(p + "_ry", (R[2] - R[6]) / 2);
      rows.emplace_back(p + "_rz", (R[3] - R[1]) / 2);
      break;
    }
    case K::ball:
      position_rows();
      break;
    case K::hinge: {
      need_rotation(a, f.frame_a, "hinge");
      need_rotation(b, f.frame_b, "hinge");
      position_rows();
      const Vec3Ex u = unit(f.axis, values, "the hinge axis");
      const auto [n1, n2] = perpendiculars(u, values);
      const Vec3Ex ua = mul(a.rotation, u);
      rows.emplace_back(p + "_n1", dot(ua, mul(b.rotation, n1)));
      rows.emplace_back(p + "_n2", dot(ua, mul(b.rotation, n2)));
      break;
    }
    case K::level: {
      need_rotation(a, f.frame_a, "level");
      const Vec3Ex u = unit(f.axis, values, "the level axis");
      const Vec3Ex up = unit(f.up, values, "the level up direction");
      const Vec3Ex ua = mul(a.rotation, u);
      if (f.vertical) {
        const auto [e1, e2] = perpendiculars(up, values);
        rows.emplace_back(p + "_v1", dot(ua, e1));
        rows.emplace_back(p + "_v2", dot(ua, e2));
      } else {
        rows.emplace_back(p, dot(ua, up));
      }
      break;
    }
    case K::distance: {
      const ex L = f.length.subs(values);
      if (!(number(L, values, "the distance length") > 0.0))
        throw DefinitionError("the distance length must be positive, got " + str(f.length));
      Vec3Ex d{a.position[0] - b.position[0], a.position[1] - b.position[1],
               a.position[2] - b.position[2]};
      rows.emplace_back(p, (dot(d, d) - L * L) / 2);
      break;
    }
  }
  return rows;
}

// A pose of 12 fresh symbols (position, rotation) and its substitution by the real pose.
struct SymbolPose {
  std::array<GiNaC::symbol, 3> p;
  std::array<GiNaC::symbol, 9> R;
  [[nodiscard]] FramePose pose(bool has_rotation) const {
    FramePose f;
    for (std::size_t k = 0; k < 3; ++k) f.position[k] = p[k];
    for (std::size_t k = 0; k < 9; ++k) f.rotation[k] = R[k];
    f.has_rotation = has_rotation;
    return f;
  }
  void substitution(const FramePose& real, GiNaC::exmap& m) const {
    for (std::size_t k = 0; k < 3; ++k) m[p[k]] = real.position[k];
    for (std::size_t k = 0; k < 9; ++k) m[R[k]] = real.rotation[k];
  }
};

// Row i of G = ∂Φ/∂(twist): [∂Φ/∂p, Σ ∂Φ/∂R_rc ([e_k]× R)_rc] (Ṙ = [ω]× R, world ω).
std::array<ex, 6> twist_map(const ex& phi, const SymbolPose& s) {
  std::array<ex, 6> g;
  for (std::size_t j = 0; j < 3; ++j) g[j] = phi.diff(s.p[j]);
  for (std::size_t k = 0; k < 3; ++k) {
    Mat3Ex E{0, 0, 0, 0, 0, 0, 0, 0, 0};  // [e_k]×
    if (k == 0) E = {0, 0, 0, 0, 0, -1, 0, 1, 0};
    if (k == 1) E = {0, 0, 1, 0, 0, 0, -1, 0, 0};
    if (k == 2) E = {0, -1, 0, 1, 0, 0, 0, 0, 0};
    Mat3Ex Rs;
    for (std::size_t i = 0; i < 9; ++i) Rs[i] = s.R[i];
    const Mat3Ex ER = mul(E, Rs);
    ex sum = 0;
    for (std::size_t i = 0; i < 9; ++i) sum += phi.diff(s.R[i]) * ER[i];
    g[3 + k] = sum.expand();
  }
  return g;
}

}  // namespace

std::vector<std::pair<std::string, ex>> frame_rows(const FrameConstraintDef& f,
                                                   const GiNaC::exmap& values) {
  return rows_for(f, f.a, f.b, values);
}

void add_frame_constraint(ConstraintDef& def, const FrameConstraintDef& f) {
  const GiNaC::exmap values = def.parameter_values();
  for (auto& [name, phi] : frame_rows(f, values)) def.add_row(name, phi);
}

// ------------------------------------------------------------------------------ wrenches

namespace {

// The number of rows of f (the rows on symbolic poses).
Index row_count(const FrameConstraintDef& f, const GiNaC::exmap& values) {
  const SymbolPose sa, sb;
  return static_cast<Index>(
      rows_for(f, sa.pose(f.a.has_rotation), sb.pose(f.b.has_rotation), values).size());
}

}  // namespace

FrameWrenchMap::FrameWrenchMap(const FrameConstraintDef& f,
                               const std::vector<std::string>& system_coordinates,
                               SymbolTable& symbols, const GiNaC::exmap& values)
    : FrameWrenches(f.name, f.frame_a, f.frame_b, f.kind, row_count(f, values)) {
  n_ = static_cast<Index>(system_coordinates.size());
  const SymbolPose sa, sb;
  const auto rows = rows_for(f, sa.pose(f.a.has_rotation), sb.pose(f.b.has_rotation), values);
  GiNaC::exmap real = values;
  sa.substitution(f.a, real);
  sb.substitution(f.b, real);
  std::vector<ex> out;
  for (const SymbolPose* s : {&sa, &sb}) {
    for (const auto& [name, phi] : rows) {
      for (const ex& g : twist_map(phi, *s)) out.push_back(g.subs(real).subs(values));
    }
  }
  for (const FramePose* p : {&f.a, &f.b}) {
    for (const ex& e : p->position) out.push_back(e.subs(values));
    for (const ex& e : p->rotation) out.push_back(e.subs(values));
  }
  const InputMap in = coordinate_inputs(symbols, system_coordinates, InputSet::q);
  std::vector<GiNaC::symbol> q;
  for (const auto& c : system_coordinates) q.push_back(coordinate_symbol(symbols, c));
  // Twist Jacobians: v = Σ ∂p/∂q_j q̇_j, ω = Σ vee(∂R/∂q_j Rᵀ) q̇_j.
  for (const FramePose* p : {&f.a, &f.b}) {
    Mat3Ex R;
    for (std::size_t k = 0; k < 9; ++k) R[k] = p->rotation[k].subs(values);
    std::vector<ex> Jv(3 * system_coordinates.size()), Jw(3 * system_coordinates.size());
    for (std::size_t j = 0; j < q.size(); ++j) {
      Mat3Ex dR;
      for (std::size_t k = 0; k < 9; ++k) dR[k] = R[k].diff(q[j]);
      const Mat3Ex W = mul(dR, transposed(R));
      for (std::size_t k = 0; k < 3; ++k)
        Jv[k * q.size() + j] = p->position[k].subs(values).diff(q[j]);
      Jw[0 * q.size() + j] = W[7];
      Jw[1 * q.size() + j] = W[2];
      Jw[2 * q.size() + j] = W[3];
    }
    out.insert(out.end(), Jv.begin(), Jv.end());
    out.insert(out.end(), Jw.begin(), Jw.end());
  }
  for (auto& e : out) e = e.expand();
  tape_ = Tape(out, in);
}

void FrameWrenchMap::maps(const Vec& q, Mat& Ga, Mat& Gb) const {
  std::vector<double> out(tape_.outputs());
  tape_.eval(0.0, q.data(), nullptr, out.data());
  const Index m = rows();
  Ga.resize(m, 6);
  Gb.resize(m, 6);
  std::size_t k = 0;
  for (Index i = 0; i < m; ++i)
    for (Index j = 0; j < 6; ++j) Ga(i, j) = out[k++];
  for (Index i = 0; i < m; ++i)
    for (Index j = 0; j < 6; ++j) Gb(i, j) = out[k++];
}

void FrameWrenchMap::jacobians(const Vec& q, Mat& Ja, Mat& Jb) const {
  std::vector<double> out(tape_.outputs());
  tape_.eval(0.0, q.data(), nullptr, out.data());
  std::size_t k = static_cast<std::size_t>(12 * rows() + 24);
  for (Mat* J : {&Ja, &Jb}) {
    J->resize(6, n_);
    for (Index r = 0; r < 6; ++r)
      for (Index j = 0; j < n_; ++j) (*J)(r, j) = out[k++];
  }
}

void FrameWrenchMap::jacobians(CVecRef q, Workspace& ws, Mat& Ja, Mat& Jb) const {
  tape_.eval(0.0, q.data(), nullptr, ws.out.data(), ws.work.data());
  auto k = static_cast<std::size_t>(12 * rows() + 24);
  for (Mat* J : {&Ja, &Jb}) {
    for (Index r = 0; r < 6; ++r)
      for (Index j = 0; j < n_; ++j) (*J)(r, j) = ws.out[k++];
  }
}

FrameWrenchMap::Workspace FrameWrenchMap::workspace() const {
  return Workspace{std::vector<double>(tape_.outputs()), std::vector<double>(tape_.work_size()),
                   Mat(rows(), 6), Mat(rows(), 6)};
}

void FrameWrenchMap::evaluate(CVecRef q, const Vec& lambda, Workspace& ws, FrameWrench& w) const {
  std::vector<double>& out = ws.out;
  tape_.eval(0.0, q.data(), nullptr, out.data(), ws.work.data());
  Mat& Ga = ws.Ga;
  Mat& Gb = ws.Gb;
  const Index m = rows();
  std::size_t k = 0;
  for (Index i = 0; i < m; ++i)
    for (Index j = 0; j < 6; ++j) Ga(i, j) = out[k++];
  for (Index i = 0; i < m; ++i)
    for (Index j = 0; j < 6; ++j) Gb(i, j) = out[k++];
  for (auto [p, R] : {std::pair{&w.position_a, &w.rotation_a}, {&w.position_b, &w.rotation_b}}) {
    for (Index i = 0; i < 3; ++i) (*p)(i) = out[k++];
    for (Index i = 0; i < 3; ++i)
      for (Index j = 0; j < 3; ++j) (*R)(i, j) = out[k++];
  }
  wrench_from_maps(Ga, Gb, lambda, w);
}

void wrench_from_maps(const Mat& Ga, const Mat& Gb, const Vec& lambda, FrameWrench& w) {
  const Eigen::Matrix<double, 6, 1> wa = Ga.transpose() * lambda;
  const Eigen::Matrix<double, 6, 1> wb = Gb.transpose() * lambda;
  w.force_a = wa.head<3>();
  w.moment_a = wa.tail<3>();
  w.force_b = wb.head<3>();
  w.moment_b = wb.tail<3>();
  w.force_a_local = w.rotation_a.transpose() * w.force_a;
  w.moment_a_local = w.rotation_a.transpose() * w.moment_a;
  w.force_b_local = w.rotation_b.transpose() * w.force_b;
  w.moment_b_local = w.rotation_b.transpose() * w.moment_b;
}

FrameWrench FrameWrenches::evaluate(const Vec& q, const Vec& lambda) const {
  Workspace ws = workspace();
  FrameWrench w;
  evaluate(q, lambda, ws, w);
  return w;
}

std::shared_ptr<FrameConstraint> make_frame_constraint(const ConstraintDef& def,
                                                       const FrameConstraintDef& f) {
  auto derived = make_constraint(def);
  return std::make_shared<FrameConstraint>(
      derived,
      std::make_shared<FrameWrenchMap>(f, def.system_coordinates(), def.symbols(),
                                       def.parameter_values()),
      derived);
}

}  // namespace ukdyn::symbolic
