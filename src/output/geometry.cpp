#include "ukdyn/output/geometry.hpp"

#include <fmt/format.h>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <map>
#include <memory>

#include "scenario/definitions_loader.hpp"
#include "ukdyn/paper_robot/cooperative_constraints.hpp"
#include "ukdyn/paper_robot/mobile_manipulator.hpp"
#include "ukdyn/robot_files/visuals.hpp"
#include "ukdyn/scenario/scenario.hpp"
#include "ukdyn/symbolic/expression.hpp"
#include "ukdyn/symbolic/tape.hpp"
#include "ukdyn/symbolic/tape_inputs.hpp"
#include "ukdyn/tree/tree.hpp"

namespace ukdyn {

std::size_t Geometry::add_part(std::vector<GeometryPoint> points,
                               std::vector<GeometrySegment> segments, PartFunction positions) {
  const std::size_t first = points_.size();
  parts_.push_back({first, points.size(), std::move(positions)});
  for (auto& p : points) points_.push_back(std::move(p));
  for (auto& s : segments) {
    s.a += first;
    s.b += first;
    segments_.push_back(std::move(s));
  }
  return first;
}

long Geometry::find(const std::string& name) const {
  for (std::size_t i = 0; i < points_.size(); ++i) {
    if (points_[i].name == name) return static_cast<long>(i);
  }
  return -1;
}

void Geometry::evaluate(CVecRef q, std::vector<Vec3>& out) const {
  out.resize(points_.size());
  for (const auto& p : parts_) p.f(q, out, p.first);
}

void Geometry::add_solid(GeometrySolid s, OrientationFunction orientation) {
  solids_.push_back(std::move(s));
  orientations_.push_back(std::move(orientation));
}

void Geometry::evaluate_orientations(CVecRef q, std::vector<std::array<double, 4>>& out) const {
  out.resize(solids_.size());
  for (std::size_t i = 0; i < solids_.size(); ++i) out[i] = orientations_[i](q);
}

namespace {

// The paper's arm (mobile_manipulator.hpp): platform at (Δx, Δy, 0), joint r on top of it at height
// l_r, then links 1..3 in the vertical plane turned by δ, each of length l_k at absolute pitch θ_k:
// joint k+1 = joint k + l_k (cos θ_k cos δ, cos θ_k sin δ, sin θ_k). The last one is the cut point
// (MobileManipulator::cut_point, the same sum).
void add_mobile_manipulator(Geometry& g, const std::string& name,
                            std::shared_ptr<const MobileManipulator> arm, Index offset) {
  std::vector<GeometryPoint> pts{{name + ".platform", "platform"},
                                 {name + ".r", "joint"},
                                 {name + ".j2", "joint"},
                                 {name + ".j3", "grasp"},
                                 {name + ".cut", "cut"}};
  std::vector<GeometrySegment> segs{{0, 1, "base"}, {1, 2, "link"}, {2, 3, "link"}, {3, 4, "load"}};
  g.add_part(std::move(pts), std::move(segs),
             [arm, offset](CVecRef q, std::vector<Vec3>& out, std::size_t first) {
               const auto& p = arm->params();
               const auto qs = q.segment(offset, 6);
               const double cd = std::cos(qs(2)), sd = std::sin(qs(2));
               Vec3 x(qs(0), qs(1), 0.0);
               out[first] = x;
               x.z() = p.base_length;
               out[first + 1] = x;
               for (int k = 0; k < 3; ++k) {
                 const double l = p.link_length[static_cast<std::size_t>(k)];
                 const double th = qs(3 + k);
                 x += Vec3(l * std::cos(th) * cd, l * std::cos(th) * sd, l * std::sin(th));
                 out[first + 2 + static_cast<std::size_t>(k)] = x;
               }
             });
}

// A serial chain (or URDF robot): every link frame origin joined to its parent's, the chain's
// named points joined to their link's origin, and the CoM of every body; all from one compiled tape
// of the expressions symbolic::build_chain made (parameters substituted).
void add_chain(Geometry& g, const std::string& name, const symbolic::ChainModel& model,
               const std::vector<std::pair<std::string, std::string>>& edges, const System& sys) {
  namespace sym = symbolic;
  sym::SymbolTable& syms = model.def.symbols();
  // Coordinates without a symbol are in none of the expressions (and not added).
  const sym::InputMap in =
      sym::coordinate_inputs(syms, sys.coordinate_names(), sym::InputSet::q_interned);
  const GiNaC::exmap values = model.def.parameter_values();
  std::vector<GeometryPoint> pts;
  std::vector<GiNaC::ex> ex;
  std::map<std::string, std::size_t> index;
  auto add = [&](const std::string& n, const std::string& kind, const sym::Vec3Ex& p) {
    pts.push_back({name + "." + n, kind});
    for (const auto& e : p) ex.push_back(e.subs(values).expand());
    index[n] = pts.size() - 1;
  };
  for (const auto& [ln, pose] : model.links) add(ln, "joint", pose.position);
  if (!edges.empty() && model.links.count(edges.front().first)) {
    pts[index[edges.front().first]].kind = "platform";  // the root link (or the mobile base)
  }
  for (const auto& [pn, p] : model.points) {
    if (!index.count(pn)) add(pn, pn == "cut" ? "cut" : "point", p);
  }
  for (const auto& b : model.def.bodies) {
    pts.push_back({name + "." + b.name + ".com", "com"});
    for (const auto& e : b.com) ex.push_back(e.subs(values).expand());
  }
  std::vector<GeometrySegment> segs;
  for (const auto& [a, b] : edges) {
    auto ia = index.find(a), ib = index.find(b);
    if (ia != index.end() && ib != index.end()) segs.push_back({ia->second, ib->second, "link"});
  }
  auto tape = std::make_shared<const sym::Tape>(ex, in);
  const std::size_t count = pts.size();
  g.add_part(std::move(pts), std::move(segs),
             [tape, count](CVecRef q, std::vector<Vec3>& out, std::size_t first) {
               std::vector<double> v(3 * count);
               tape->eval(0.0, q.data(), nullptr, v.data());
               for (std::size_t k = 0; k < count; ++k) {
                 out[first + k] = Vec3(v[3 * k], v[3 * k + 1], v[3 * k + 2]);
               }
             });
}

// A chain on the tree algorithms whose symbolic kinematics nothing built (docs/tree-algorithms.md):
// the same points as add_chain — the root or base, every link origin, the named points, the CoM of
// every link with mass — from the tree's link poses at q (the base's intermediate x / y links,
// named BASE/x, BASE/y, are not drawn).
void add_tree_chain(Geometry& g, const std::string& name,
                    std::shared_ptr<const tree::TreeSubsystem> t,
                    const std::vector<std::pair<std::string, std::string>>& edges, Index offset) {
  const tree::Model& m = t->model();
  struct Where {
    int link;  // −1: the root frame
    Vec3 xyz;  // in the link frame
  };
  std::vector<GeometryPoint> pts;
  std::vector<Where> where;
  std::map<std::string, std::size_t> index;
  auto add = [&](const std::string& n, const std::string& kind, int link, const Vec3& xyz) {
    index[n] = pts.size();
    pts.push_back({name + "." + n, kind});
    where.push_back({link, xyz});
  };
  if (!m.root_name.empty()) add(m.root_name, "joint", -1, Vec3::Zero());
  for (std::size_t i = 0; i < m.links.size(); ++i) {
    if (m.links[i].name.find('/') == std::string::npos)
      add(m.links[i].name, "joint", static_cast<int>(i), Vec3::Zero());
  }
  if (!edges.empty() && index.count(edges.front().first))
    pts[index[edges.front().first]].kind = "platform";  // the root link (or the mobile base)
  for (const auto& p : m.points) {
    if (!index.count(p.name)) add(p.name, p.name == "cut" ? "cut" : "point", p.link, p.xyz);
  }
  for (std::size_t i = 0; i < m.links.size(); ++i) {
    if (m.links[i].mass > 0.0) {
      pts.push_back({name + "." + m.links[i].name + ".com", "com"});
      where.push_back({static_cast<int>(i), m.links[i].com});
    }
  }
  std::vector<GeometrySegment> segs;
  for (const auto& [a, b] : edges) {
    auto ia = index.find(a), ib = index.find(b);
    if (ia != index.end() && ib != index.end()) segs.push_back({ia->second, ib->second, "link"});
  }
  const Index n = t->dof();
  g.add_part(std::move(pts), std::move(segs),
             [t, where, offset, n](CVecRef q, std::vector<Vec3>& out, std::size_t first) {
               std::vector<Eigen::Matrix3d> R;
               std::vector<Eigen::Vector3d> p;
               t->link_poses(q.segment(offset, n), R, p);
               const tree::Model& mm = t->model();
               for (std::size_t k = 0; k < where.size(); ++k) {
                 const int l = where[k].link;
                 out[first + k] = l < 0
                                      ? Vec3(mm.root_translation + mm.root_rotation * where[k].xyz)
                                      : Vec3(p[static_cast<std::size_t>(l)] +
                                             R[static_cast<std::size_t>(l)] * where[k].xyz);
               }
             });
}

// The inertia-equivalent box of a body of mass m and inertia tensor J about its CoM (docs/replay.md):
// the uniform box of the same mass and principal moments (MuJoCo draws the same box,
// mjVIS_INERTIA). A uniform box of edges a, b, c has I1 = m (b² + c²) / 12 and so on (any table of
// moments of inertia), hence a = sqrt(6 (I2 + I3 − I1) / m), b = sqrt(6 (I3 + I1 − I2) / m),
// c = sqrt(6 (I1 + I2 − I3) / m) along the principal axes: its edges, and the rotation whose
// columns are those axes. A side the formula makes zero (a rod) is drawn at 2 % of the largest;
// nullopt if every side is zero or the mass is not positive (a point mass: its CoM only).
std::optional<std::pair<Vec3, Eigen::Quaterniond>> inertia_box(double mass,
                                                               const Eigen::Matrix3d& J) {
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(0.5 * (J + J.transpose()));
  const Vec3 I = es.eigenvalues();
  Eigen::Matrix3d V = es.eigenvectors();
  if (V.determinant() < 0) V.col(2) *= -1.0;  // a rotation
  Vec3 size = Vec3::Zero();
  for (int i = 0; i < 3; ++i) {
    const double s = 6.0 * (I((i + 1) % 3) + I((i + 2) % 3) - I(i)) / mass;
    size(i) = mass > 0.0 && std::isfinite(s) && s > 0.0 ? std::sqrt(s) : 0.0;
  }
  if (!(size.maxCoeff() > 0.0)) return std::nullopt;
  return std::make_pair(size.cwiseMax(0.02 * size.maxCoeff()), Eigen::Quaterniond(V));
}

// The number an expression (parameters substituted) evaluates to, or nullopt (a mass of t).
std::optional<double> number_of(const GiNaC::ex& e) {
  const GiNaC::ex v = e.evalf();
  if (!GiNaC::is_a<GiNaC::numeric>(v) || !GiNaC::ex_to<GiNaC::numeric>(v).is_real())
    return std::nullopt;
  return GiNaC::ex_to<GiNaC::numeric>(v).to_double();
}

// A definitions body's inertia-equivalent box (inertia_box) and its rotation in the body frame, or
// in the world frame for `inertia_frame: world`; nullopt if its mass or inertia is not a number
// (of t) or gives no box. A scalar inertia I is the tensor I·1 (a cube).
std::optional<std::pair<Vec3, Eigen::Quaterniond>> body_box(const symbolic::BodyDef& b) {
  using Kind = symbolic::BodyDef::InertiaKind;
  const auto m = number_of(b.mass);
  if (!m || b.inertia_kind == Kind::none) return std::nullopt;
  Eigen::Matrix3d J = Eigen::Matrix3d::Zero();
  for (int k = 0; k < 9; ++k) {
    const auto v =
        number_of(b.inertia_kind == Kind::scalar ? (k % 4 == 0 ? b.inertia_scalar : GiNaC::ex(0))
                                                 : b.inertia_tensor[static_cast<std::size_t>(k)]);
    if (!v) return std::nullopt;
    J(k / 3, k % 3) = *v;
  }
  return inertia_box(*m, J);
}

// A definitions subsystem: the CoM of every body (no segments: the file says nothing of links),
// each from the tape of its `com` expressions at q, and the inertia-equivalent box of every body
// with a mass (body_box), solid NAME.BODY centred at its CoM: turned by R(q) of its `rotation`
// (the same tape) times the box's principal axes, or by the principal axes alone (axis-aligned for
// a diagonal or scalar inertia) if it has no rotation or its inertia is given in the world frame.
// Returns the index of its first point (the CoM of the first body).
std::size_t add_bodies(Geometry& g, const std::string& name,
                       const std::vector<symbolic::BodyDef>& bodies, const System& sys,
                       symbolic::SymbolTable& syms) {
  namespace sym = symbolic;
  // Coordinates without a symbol are in none of the expressions (and not added).
  const sym::InputMap in =
      sym::coordinate_inputs(syms, sys.coordinate_names(), sym::InputSet::q_interned);
  std::vector<GeometryPoint> pts;
  std::vector<GiNaC::ex> ex;
  for (const auto& b : bodies) {
    pts.push_back({name + "." + b.name, "com"});
    for (const auto& e : b.com) ex.push_back(e.expand());
  }
  const std::size_t count = pts.size();
  std::vector<long> rot_at(count, -1);  // the first output of its rotation (row-major) in the tape
  for (std::size_t k = 0; k < count; ++k) {
    if (!bodies[k].rotation || bodies[k].inertia_frame == sym::Frame::world) continue;
    rot_at[k] = static_cast<long>(ex.size());
    for (const auto& e : *bodies[k].rotation) ex.push_back(e);
  }
  auto tape = std::make_shared<const sym::Tape>(ex, in);
  const std::size_t outputs = ex.size();
  const std::size_t first =
      g.add_part(std::move(pts), {},
                 [tape, count, outputs](CVecRef q, std::vector<Vec3>& out, std::size_t at) {
                   std::vector<double> v(outputs);
                   tape->eval(0.0, q.data(), nullptr, v.data());
                   for (std::size_t k = 0; k < count; ++k)
                     out[at + k] = Vec3(v[3 * k], v[3 * k + 1], v[3 * k + 2]);
                 });
  for (std::size_t k = 0; k < count; ++k) {
    const auto box = body_box(bodies[k]);
    if (!box) continue;
    const Eigen::Quaterniond axes = box->second;
    const long r = rot_at[k];
    g.add_solid(
        {name + "." + bodies[k].name, "box", box->first, first + k, "link"},
        [tape, outputs, r, axes](CVecRef q) {
          Eigen::Quaterniond o = axes;
          if (r >= 0) {
            std::vector<double> v(outputs);
            tape->eval(0.0, q.data(), nullptr, v.data());
            const Eigen::Matrix3d R =
                Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(v.data() + r);
            o = Eigen::Quaterniond(R) * axes;
          }
          return std::array<double, 4>{o.w(), o.x(), o.y(), o.z()};
        });
  }
  return first;
}

// The rotation (link → world) and origin of chosen links at q.
using LinkPoses =
    std::function<void(CVecRef q, std::vector<Eigen::Matrix3d>& R, std::vector<Vec3>& p)>;

// The shapes a chain's robot file gives its links (ukdyn/robot_files/visuals.hpp) that the page
// draws, each with the index of its link in `links`.
struct LinkShapes {
  std::vector<symbolic::LinkVisual> shapes;
  std::vector<std::size_t> link;
  std::vector<std::string> links;
};

// Whether the shape is one the page draws.
bool drawn_kind(const std::string& shape) {
  return shape == "box" || shape == "sphere" || shape == "ellipsoid" || shape == "cylinder" ||
         shape == "capsule";
}

// Whether its extents are finite and positive and its pose finite.
bool drawable(const symbolic::LinkVisual& v) {
  bool ok = true;
  for (double x : v.size) ok = ok && std::isfinite(x) && x > 0.0;
  for (double x : v.xyz) ok = ok && std::isfinite(x);
  double n = 0.0;
  for (double x : v.quat) n += x * x;
  return ok && std::isfinite(n) && n > 0.0;
}

// Those of serial chain `name` (none if it was not read from a robot file): the file's root frame
// (an empty link) is the chain's `root`; an MJCF mesh drawn as its bounding box is named in
// left_out as "NAME.LINK (mesh M: drawn as its bounding box)"; what is not drawn (URDF meshes:
// they are not loaded; planes,
// height fields; a shape on a link the chain does not have; a file that cannot be read now) is
// named in left_out as "NAME.LINK (why)".
LinkShapes read_link_shapes(const Scenario& sc, const std::string& name, const std::string& root,
                            const std::function<bool(const std::string&)>& has_link,
                            std::vector<std::string>* left_out) {
  LinkShapes out;
  const auto file = io_detail::chain_robot_file(sc.definitions.get(), name);
  if (!file) return out;
  const auto note = [&](const std::string& what) {
    if (left_out) left_out->push_back(what);
  };
  std::vector<symbolic::LinkVisual> all;
  try {
    all = file->first == "urdf" ? symbolic::urdf_visuals(file->second)
                                : symbolic::mjcf_visuals(file->second);
  } catch (const Error& e) {
    note(fmt::format("{} (its shapes: {})", name, e.what()));
    return out;
  }
  std::map<std::string, std::size_t> index, count;
  for (auto& v : all) {
    if (v.link.empty()) v.link = root;
    const std::string where = name + "." + v.link;
    if (v.shape == "mesh") {
      note(fmt::format("{} (mesh{}{}: meshes are not loaded)", where, v.detail.empty() ? "" : " ",
                       v.detail));
    } else if (!has_link(v.link)) {
      note(fmt::format("{} ({}: no such link in the chain)", where, v.shape));
    } else if (!drawn_kind(v.shape)) {
      note(fmt::format("{} ({}: only boxes, spheres, ellipsoids, cylinders and capsules are drawn)",
                       where, v.shape));
    } else if (!drawable(v)) {
      note(fmt::format("{} ({}: a size that is not > 0, or a pose that is not finite)", where,
                       v.shape));
    } else {
      if (v.bounding_box)
        note(fmt::format("{} (mesh {}: drawn as its bounding box)", where, v.detail));
      auto [it, added] = index.emplace(v.link, out.links.size());
      if (added) out.links.push_back(v.link);
      out.link.push_back(it->second);
      v.detail = fmt::format("{}.visual{}", where, count[v.link]++);  // the solid's name
      out.shapes.push_back(std::move(v));
    }
  }
  return out;
}

// The shapes as solids (kind link), each centred at a point (kind shape) of its link's pose:
// centre p + R xyz, orientation R R_shape.
void add_link_shapes(Geometry& g, const LinkShapes& ls, LinkPoses poses) {
  if (ls.shapes.empty()) return;
  std::vector<GeometryPoint> pts;
  std::vector<Vec3> xyz;
  std::vector<Eigen::Quaterniond> rot;
  for (const auto& v : ls.shapes) {
    pts.push_back({v.detail, "shape"});
    xyz.emplace_back(v.xyz[0], v.xyz[1], v.xyz[2]);
    rot.push_back(Eigen::Quaterniond(v.quat[0], v.quat[1], v.quat[2], v.quat[3]).normalized());
  }
  auto shared = std::make_shared<const LinkPoses>(std::move(poses));
  const std::vector<std::size_t> link = ls.link;
  const std::size_t first = g.add_part(
      std::move(pts), {}, [shared, link, xyz](CVecRef q, std::vector<Vec3>& out, std::size_t at) {
        std::vector<Eigen::Matrix3d> R;
        std::vector<Vec3> p;
        (*shared)(q, R, p);
        for (std::size_t k = 0; k < link.size(); ++k)
          out[at + k] = p[link[k]] + R[link[k]] * xyz[k];
      });
  for (std::size_t k = 0; k < ls.shapes.size(); ++k) {
    const auto& v = ls.shapes[k];
    const std::size_t l = link[k];
    const Eigen::Quaterniond r = rot[k];
    g.add_solid({v.detail, v.shape, Vec3(v.size[0], v.size[1], v.size[2]), first + k, "link"},
                [shared, l, r](CVecRef q) {
                  std::vector<Eigen::Matrix3d> R;
                  std::vector<Vec3> p;
                  (*shared)(q, R, p);
                  const Eigen::Quaterniond o = Eigen::Quaterniond(R[l]) * r;
                  return std::array<double, 4>{o.w(), o.x(), o.y(), o.z()};
                });
  }
}

// The wheels of a wheeled platform (docs/wheeled-platforms.md) drawn by add_bodies' points: wheel K
// (body wheelK, its hub at height r) as the cylinder NAME.wheelK of diameter 2 r and width 0.4 r
// (the model has no width) along its axle: the cylinder's z turned to s = (−sin β, cos β, 0) of the
// platform frame by Rz(β) Rx(−π/2), then by the platform's yaw Rz(ψ), ψ its third coordinate.
// The platform itself (its scalar inertia is the yaw inertia I alone) as a deck: a square slab
// whose moment about z is I, m (s² + s²) / 12 = I, so s = sqrt(6 I / m), 0.3 r thick, at its CoM
// raised to the hubs' height r (the planar model puts the CoM at z = 0), turned by Rz(ψ).
void add_platform_deck(Geometry& g, const std::string& name, double r, const symbolic::BodyDef& b,
                       std::size_t com, Index offset) {
  const auto m = number_of(b.mass);
  const auto I = number_of(b.inertia_scalar);
  if (!m || !I || !(*m > 0.0) || !(*I > 0.0)) return;
  const double side = std::sqrt(6.0 * *I / *m);
  // Parts are evaluated in order (Geometry::evaluate): the CoM is written before this point.
  const std::size_t deck = g.add_part({{name + ".deck", "shape"}}, {},
                                      [com, r](CVecRef, std::vector<Vec3>& out, std::size_t at) {
                                        out[at] = out[com] + Vec3(0, 0, r);
                                      });
  g.add_solid({name + ".platform", "box", Vec3(side, side, 0.3 * r), deck, "link"},
              [offset](CVecRef q) {
                const Eigen::Quaterniond o(Eigen::AngleAxisd(q(offset + 2), Vec3::UnitZ()));
                return std::array<double, 4>{o.w(), o.x(), o.y(), o.z()};
              });
}

void add_wheels(Geometry& g, const std::string& name, const io_detail::PlatformWheels& wheels,
                const std::vector<symbolic::BodyDef>& bodies, std::size_t first, Index offset) {
  const double r = wheels.radius;
  for (std::size_t k = 0; k < bodies.size(); ++k)
    if (bodies[k].name == "platform") add_platform_deck(g, name, r, bodies[k], first + k, offset);
  for (std::size_t k = 0; k < wheels.headings.size(); ++k) {
    const std::string body = "wheel" + std::to_string(k + 1);
    const auto it = std::find_if(bodies.begin(), bodies.end(),
                                 [&](const symbolic::BodyDef& b) { return b.name == body; });
    if (it == bodies.end()) continue;
    const Eigen::Quaterniond axle =
        Eigen::Quaterniond(Eigen::AngleAxisd(wheels.headings[k], Vec3::UnitZ())) *
        Eigen::Quaterniond(Eigen::AngleAxisd(-M_PI / 2, Vec3::UnitX()));
    const std::size_t point = first + static_cast<std::size_t>(it - bodies.begin());
    g.add_solid({name + "." + body, "cylinder", Vec3(2 * r, 2 * r, 0.4 * r), point, "link"},
                [axle, offset](CVecRef q) {
                  const Eigen::Quaterniond o =
                      Eigen::Quaterniond(Eigen::AngleAxisd(q(offset + 2), Vec3::UnitZ())) * axle;
                  return std::array<double, 4>{o.w(), o.x(), o.y(), o.z()};
                });
  }
}

// The poses of `links` of a chain with symbolic kinematics: one compiled tape of their
// build_chain origins and rotations (parameters substituted), as add_chain's points.
LinkPoses chain_link_poses(const symbolic::ChainModel& model, const std::vector<std::string>& links,
                           const System& sys) {
  namespace sym = symbolic;
  if (links.empty()) return {};
  const sym::InputMap in = sym::coordinate_inputs(model.def.symbols(), sys.coordinate_names(),
                                                  sym::InputSet::q_interned);
  const GiNaC::exmap values = model.def.parameter_values();
  std::vector<GiNaC::ex> ex;
  for (const auto& l : links) {
    const sym::LinkPose& pose = model.links.at(l);
    for (const auto& e : pose.position) ex.push_back(e.subs(values).expand());
    for (const auto& e : pose.rotation) ex.push_back(e.subs(values).expand());  // row-major
  }
  auto tape = std::make_shared<const sym::Tape>(ex, in);
  const std::size_t n = links.size();
  return [tape, n](CVecRef q, std::vector<Eigen::Matrix3d>& R, std::vector<Vec3>& p) {
    std::vector<double> v(12 * n);
    tape->eval(0.0, q.data(), nullptr, v.data());
    R.resize(n);
    p.resize(n);
    for (std::size_t k = 0; k < n; ++k) {
      p[k] = Vec3(v[12 * k], v[12 * k + 1], v[12 * k + 2]);
      R[k] = Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(v.data() + 12 * k + 3);
    }
  };
}

// The same from the tree algorithms' link poses (the root frame for the model's root name).
LinkPoses tree_link_poses(std::shared_ptr<const tree::TreeSubsystem> t,
                          const std::vector<std::string>& links, Index offset) {
  const tree::Model& m = t->model();
  std::vector<int> idx;
  for (const auto& l : links) {
    int i = -1;
    for (std::size_t k = 0; k < m.links.size(); ++k)
      if (m.links[k].name == l) i = static_cast<int>(k);
    idx.push_back(i);
  }
  const Index n = t->dof();
  return [t, idx, offset, n](CVecRef q, std::vector<Eigen::Matrix3d>& R, std::vector<Vec3>& p) {
    std::vector<Eigen::Matrix3d> RL;
    std::vector<Eigen::Vector3d> pL;
    t->link_poses(q.segment(offset, n), RL, pL);
    const tree::Model& mm = t->model();
    R.resize(idx.size());
    p.resize(idx.size());
    for (std::size_t k = 0; k < idx.size(); ++k) {
      const int i = idx[k];
      R[k] = i < 0 ? mm.root_rotation : RL[static_cast<std::size_t>(i)];
      p[k] = i < 0 ? Vec3(mm.root_translation) : Vec3(pL[static_cast<std::size_t>(i)]);
    }
  };
}

// A free body (docs/free-bodies.md): its CoM, and its inertia-equivalent box (inertia_box). Posed
// by the coordinates (x, y, z, qw, qx, qy, qz): CoM at (x, y, z), turned by the normalised
// quaternion and then by the principal axes in the body frame (no box: only the CoM is drawn). A free body with a
// `shape:` is drawn as that shape instead, centred at the CoM, its axes the body's.
void add_free_body(Geometry& g, const std::string& name, const io_detail::FreeBodyInertia& fb,
                   const std::optional<io_detail::FreeBodyShape>& shape, Index offset) {
  const std::size_t centre =
      g.add_part({{name + "." + name, "com"}}, {},
                 [offset](CVecRef q, std::vector<Vec3>& out, std::size_t first) {
                   out[first] = q.segment<3>(offset);
                 });
  const auto posed = [offset](const Eigen::Quaterniond& in_body) {
    return [offset, in_body](CVecRef q) {
      Eigen::Quaterniond r(q(offset + 3), q(offset + 4), q(offset + 5), q(offset + 6));
      const double n = r.norm();
      r = n > 0.0 ? Eigen::Quaterniond(r.coeffs() / n) : Eigen::Quaterniond::Identity();
      const Eigen::Quaterniond o = r * in_body;
      return std::array<double, 4>{o.w(), o.x(), o.y(), o.z()};
    };
  };
  if (shape) {
    const Vec3 size(shape->size[0], shape->size[1], shape->size[2]);
    g.add_solid({name, shape->shape, size, centre}, posed(Eigen::Quaterniond::Identity()));
    return;
  }
  Eigen::Matrix3d J;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) J(i, j) = fb.inertia[static_cast<std::size_t>(3 * i + j)];
  const auto box = inertia_box(fb.mass, J);
  if (box) g.add_solid({name, "box", box->first, centre}, posed(box->second));
}

}  // namespace

Geometry build_geometry(const Scenario& sc, std::vector<std::string>* left_out) {
  Geometry g;
  const System& sys = *sc.system;
  for (std::size_t k = 0; k < sc.subsystems.size(); ++k) {
    const auto& info = sc.subsystems[k];
    const auto& sub = sys.subsystems()[k];
    if (auto arm = std::dynamic_pointer_cast<const MobileManipulator>(sub)) {
      add_mobile_manipulator(g, info.name, arm, info.offset);
    } else if (const auto* chain = io_detail::chain_model(sc.definitions.get(), info.name)) {
      const auto edges = io_detail::chain_edges(sc.definitions.get(), info.name);
      add_chain(g, info.name, *chain, edges, sys);
      const LinkShapes ls = read_link_shapes(
          sc, info.name, edges.empty() ? "" : edges.front().first,
          [&](const std::string& l) { return chain->links.count(l) > 0; }, left_out);
      add_link_shapes(g, ls, chain_link_poses(*chain, ls.links, sys));
    } else if (auto tr = std::dynamic_pointer_cast<const tree::TreeSubsystem>(sub)) {
      const auto edges = io_detail::chain_edges(sc.definitions.get(), info.name);
      add_tree_chain(g, info.name, tr, edges, info.offset);
      const tree::Model& m = tr->model();
      const LinkShapes ls = read_link_shapes(
          sc, info.name, edges.empty() ? m.root_name : edges.front().first,
          [&](const std::string& l) {
            return l == m.root_name ||
                   std::any_of(m.links.begin(), m.links.end(),
                               [&](const tree::Link& link) { return link.name == l; });
          },
          left_out);
      add_link_shapes(g, ls, tree_link_poses(tr, ls.links, info.offset));
    } else if (const auto bodies =
                   io_detail::definitions_body_defs(sc.definitions.get(), info.name);
               !bodies.empty() &&
               std::dynamic_pointer_cast<const symbolic::DerivedSubsystem>(sub)) {
      // The table of the CoMs' symbols: the derived subsystem's (the scenario's).
      const auto wheels = io_detail::platform_wheels(sc.definitions.get(), info.name);
      auto drawn = bodies;  // a platform's body is drawn as its deck (add_wheels), not a cube
      for (auto& b : drawn)
        if (wheels && b.name == "platform") b.inertia_kind = symbolic::BodyDef::InertiaKind::none;
      const std::size_t first = add_bodies(
          g, info.name, drawn, sys,
          *std::dynamic_pointer_cast<const symbolic::DerivedSubsystem>(sub)->derivation().symbols);
      if (wheels) add_wheels(g, info.name, *wheels, bodies, first, info.offset);
    } else if (const auto fb = io_detail::free_body_inertia(sc.definitions.get(), info.name);
               fb && info.type == "free_body") {
      add_free_body(g, info.name, *fb, io_detail::free_body_shape(sc.definitions.get(), info.name),
                    info.offset);
    } else if (left_out) {
      left_out->push_back(info.name);
    }
  }
  return g;
}

}  // namespace ukdyn
