// Real arms on the recursive tree algorithms (docs/tree-algorithms.md), side by side with MuJoCo
// on the same MJCF file (robots/panda.xml, robots/ur5e.xml):
//   tree/<robot>_dynamics      M, C q̇, G (TreeSubsystem::dynamics, the caller's slot)
//   tree/<robot>_forward       q̈ of the unconstrained arm (forward(): dynamics + solve)
//   mujoco/<robot>_mj_forward  mj_forward on the same file (MuJoCo's CRB + RNE + factorisation)
//   tree/chain_<N>_mass, _bias M and C q̇ + G of an N-link spatial chain (cost against N)
//   tree/chain_<N>_id_jacobian, _frame_jacobian
//                              its ∂ID/∂(q, q̇) and its tip frame's columns (the derivatives'
//                              passes, docs/derivatives.md "Cost")
//   tree/floating_<robot>_id_jacobian, _frame_jacobian
//                              the same for the arm on a free joint (its MJCF file with a
//                              <freejoint> on the base: a ball joint's similarity motions)
//   scenario/<name>_forward    forward() of a shipped scenario at its initial state (the arms on
//                              trees, their welds to the load numeric), when built with io
//   mujoco/two_pandas_weld_mj_forward
//                              mj_forward on bench/two_pandas_weld.xml, the MJCF twin of
//                              scenarios/two_pandas_weld.yaml (two Pandas on x, y, yaw platforms
//                              welded to a free plate: MuJoCo's weld equalities, its default Newton
//                              solver, no contacts), at the same state (keyframe 'grasp')
#include <benchmark/benchmark.h>

#include <Eigen/Geometry>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "bench_common.hpp"
#include "ukdyn/model/system.hpp"
#include "ukdyn/robot_files/mjcf.hpp"
#include "ukdyn/symbolic/chain_tree.hpp"
#include "ukdyn/tree/tree.hpp"

#ifdef UKDYN_BENCH_HAVE_MUJOCO
#include <mujoco/mujoco.h>
#endif
#ifdef UKDYN_BENCH_HAVE_IO
#include "ukdyn/model/linearize.hpp"
#include "ukdyn/scenario/scenario.hpp"
#endif

namespace ukbench {
namespace {

namespace sym = ukdyn::symbolic;
using ukdyn::Index;
using ukdyn::Mat;
using ukdyn::Vec;

std::string robot_file(const std::string& robot, const char* ext) {
  return std::string(UKDYN_BENCH_SOURCE_DIR) + "/robots/" + robot + "." + ext;
}

std::shared_ptr<const ukdyn::tree::TreeSubsystem> robot_tree(const std::string& robot, int dof) {
  std::vector<std::string> q;
  for (int i = 1; i <= dof; ++i) q.push_back("q" + std::to_string(i));
  sym::ChainDef c(robot, q);
  sym::append_mjcf(c, robot_file(robot, "xml"), /*gravity=*/true);
  sym::ChainTree t = sym::chain_tree(c);
  if (!t.model) throw ukdyn::Error(robot + ": " + t.reason);
  return ukdyn::tree::make_subsystem(std::move(*t.model));
}

// A state away from every symmetry.
void state(Index n, Vec& q, Vec& qd) {
  q.resize(n);
  qd.resize(n);
  for (Index i = 0; i < n; ++i) {
    q[i] = 0.3 + 0.17 * static_cast<double>(i);
    qd[i] = 0.5 - 0.11 * static_cast<double>(i);
  }
}

void register_robot(const std::string& robot, int dof) {
  benchmark::RegisterBenchmark(("tree/" + robot + "_dynamics").c_str(),
                               [robot, dof](benchmark::State& st) {
                                 const auto t = robot_tree(robot, dof);
                                 Vec q, qd, Cqd(dof), G(dof);
                                 state(dof, q, qd);
                                 Mat M(dof, dof);
                                 std::vector<double> slot(static_cast<std::size_t>(t->slot_size()));
                                 for (auto _ : st) {
                                   t->dynamics({0.0, ukdyn::Slot(slot)}, q, qd, M, Cqd, G);
                                   benchmark::DoNotOptimize(M.data());
                                   benchmark::DoNotOptimize(Cqd.data());
                                 }
                               });
  benchmark::RegisterBenchmark(("tree/" + robot + "_forward").c_str(),
                               [robot, dof](benchmark::State& st) {
                                 ukdyn::System sys;
                                 sys.add_subsystem(robot_tree(robot, dof));
                                 ukdyn::ForwardData data(sys);
                                 Vec q, qd;
                                 state(dof, q, qd);
                                 const Vec tau = Vec::Zero(dof);
                                 for (auto _ : st) {
                                   ukdyn::forward(sys, data, 0.0, q, qd, tau);
                                   benchmark::DoNotOptimize(data.qdd.data());
                                 }
                               });
#ifdef UKDYN_BENCH_HAVE_MUJOCO
  benchmark::RegisterBenchmark(("mujoco/" + robot + "_mj_forward").c_str(),
                               [robot, dof](benchmark::State& st) {
                                 char err[1000] = "";
                                 const std::string f = robot_file(robot, "xml");
                                 mjModel* m = mj_loadXML(f.c_str(), nullptr, err, sizeof err);
                                 if (m == nullptr) {
                                   st.SkipWithError(err);
                                   return;
                                 }
                                 mjData* d = mj_makeData(m);
                                 Vec q, qd;
                                 state(dof, q, qd);
                                 for (int i = 0; i < dof; ++i) {
                                   d->qpos[i] = q[i];
                                   d->qvel[i] = qd[i];
                                 }
                                 for (auto _ : st) {
                                   mj_forward(m, d);
                                   benchmark::DoNotOptimize(d->qacc);
                                 }
                                 mj_deleteData(d);
                                 mj_deleteModel(m);
                               });
#endif
}

// An N-link spatial chain: revolute joints about z and y in turn, 0.3 m apart along x.
std::shared_ptr<const ukdyn::tree::TreeSubsystem> chain(int n) {
  ukdyn::tree::Model m;
  m.name = "chain";
  m.gravity = {0, 0, -9.81};
  for (int i = 0; i < n; ++i) {
    m.coordinates.push_back("q" + std::to_string(i));
    ukdyn::tree::Link l;
    l.name = "l" + std::to_string(i);
    l.joint = "j" + std::to_string(i);
    l.parent = i - 1;
    l.type = ukdyn::tree::JointType::revolute;
    l.axis = i % 2 == 0 ? Eigen::Vector3d::UnitZ() : Eigen::Vector3d::UnitY();
    l.origin_translation = {i == 0 ? 0.0 : 0.3, 0, 0};
    l.terms = {{i, 1.0}};
    l.mass = 1.0;
    l.com = {0.15, 0, 0};
    l.inertia = Eigen::Vector3d(0.01, 0.02, 0.02).asDiagonal();
    m.links.push_back(l);
  }
  return ukdyn::tree::make_subsystem(std::move(m));
}

// robots/ROBOT.xml on a free joint (its base given a mass and an inertia), written to the system's
// temporary directory: the arm on a floating base (7 + dof coordinates).
std::shared_ptr<const ukdyn::tree::TreeSubsystem> floating_tree(const std::string& robot, int dof) {
  std::ifstream in(robot_file(robot, "xml"));
  std::stringstream text;
  text << in.rdbuf();
  std::string xml = text.str();
  const std::string base = "<body name=\"base_link\">";
  const std::size_t at = xml.find(base);
  if (at == std::string::npos) throw ukdyn::Error(robot + ": no base_link");
  xml.insert(at + base.size(),
             "<freejoint name=\"root\"/><inertial pos=\"0.02 -0.01 0.05\" mass=\"4\" "
             "fullinertia=\"0.03 0.04 0.035 0.002 -0.001 0.003\"/>");
  const std::string path =
      (std::filesystem::temp_directory_path() / ("ukdyn_bench_floating_" + robot + ".xml"))
          .string();
  std::ofstream(path) << xml;
  std::vector<std::string> q = {"x", "y", "z", "qw", "qx", "qy", "qz"};
  for (int i = 1; i <= dof; ++i) q.push_back("q" + std::to_string(i));
  sym::ChainDef c("floating_" + robot, q);
  sym::append_mjcf(c, path, /*gravity=*/true);
  sym::ChainTree t = sym::chain_tree(c);
  if (!t.model) throw ukdyn::Error(robot + ": " + t.reason);
  return ukdyn::tree::make_subsystem(std::move(*t.model));
}

// ∂ID/∂(q, q̇) of an arm on a floating base (a ball joint's similarity motions and the symbolic
// body rate's correction terms in the analytic pass) and its flange frame's columns.
void register_floating(const std::string& robot, int dof) {
  const auto state_of = [dof](Vec& q, Vec& qd, Vec& qdd) {
    state(7 + dof, q, qd);
    q.segment(3, 4).normalize();
    qdd = qd.reverse();
  };
  benchmark::RegisterBenchmark(
      ("tree/floating_" + robot + "_id_jacobian").c_str(),
      [robot, dof, state_of](benchmark::State& st) {
        const auto t = floating_tree(robot, dof);
        const Index n = t->dof();
        Vec q, qd, qdd;
        state_of(q, qd, qdd);
        Mat Jq(n, n), Jqd(n, n);
        std::vector<double> slot(static_cast<std::size_t>(t->slot_size()));
        for (auto _ : st) {
          t->inverse_dynamics_jacobian({0.0, ukdyn::Slot(slot)}, q, qd, qdd, Jq, Jqd);
          benchmark::DoNotOptimize(Jq.data());
        }
      });
  benchmark::RegisterBenchmark(
      ("tree/floating_" + robot + "_frame_jacobian").c_str(),
      [robot, dof, state_of](benchmark::State& st) {
        const auto t = floating_tree(robot, dof);
        const Index n = t->dof();
        Vec q, qd, qdd;
        state_of(q, qd, qdd);
        Mat J(t->frame_jacobian_rows(), 2 * n);
        std::vector<double> b(12 * static_cast<std::size_t>(n));
        ukdyn::tree::FrameState value(b.data(), b.data() + 3 * n, n);
        std::vector<double> slot(static_cast<std::size_t>(t->slot_size()));
        const int tip = static_cast<int>(t->model().links.size()) - 1;
        for (auto _ : st) {
          t->frame_state_jacobian(q, qd, qdd, tip, Eigen::Matrix3d::Identity(),
                                  Eigen::Vector3d(0.0, 0.0, 0.1), {}, ukdyn::Slot(slot), value, J);
          benchmark::DoNotOptimize(J.data());
        }
      });
}

void register_chains() {
  for (int n : {7, 15, 30, 60}) {
    benchmark::RegisterBenchmark(
        ("tree/chain_" + std::to_string(n) + "_id_jacobian").c_str(), [n](benchmark::State& st) {
          const auto t = chain(n);
          Vec q, qd;
          state(n, q, qd);
          const Vec qdd = qd.reverse();
          Mat Jq(n, n), Jqd(n, n);
          std::vector<double> slot(static_cast<std::size_t>(t->slot_size()));
          for (auto _ : st) {
            t->inverse_dynamics_jacobian({0.0, ukdyn::Slot(slot)}, q, qd, qdd, Jq, Jqd);
            benchmark::DoNotOptimize(Jq.data());
          }
        });
    benchmark::RegisterBenchmark(
        ("tree/chain_" + std::to_string(n) + "_frame_jacobian").c_str(), [n](benchmark::State& st) {
          const auto t = chain(n);
          Vec q, qd;
          state(n, q, qd);
          const Vec qdd = qd.reverse();
          Mat J(t->frame_jacobian_rows(), 2 * n);
          std::vector<double> b(12 * static_cast<std::size_t>(n));
          ukdyn::tree::FrameState value(b.data(), b.data() + 3 * n, n);
          std::vector<double> slot(static_cast<std::size_t>(t->slot_size()));
          for (auto _ : st) {
            t->frame_state_jacobian(q, qd, qdd, n - 1, Eigen::Matrix3d::Identity(),
                                    Eigen::Vector3d(0.3, 0, 0), {}, ukdyn::Slot(slot), value, J);
            benchmark::DoNotOptimize(J.data());
          }
        });
    benchmark::RegisterBenchmark(
        ("tree/chain_" + std::to_string(n) + "_mass").c_str(), [n](benchmark::State& st) {
          const auto t = chain(n);
          Vec q, qd;
          state(n, q, qd);
          Mat M(n, n);
          std::vector<double> slot(static_cast<std::size_t>(t->slot_size()));
          for (auto _ : st) {
            t->mass({0.0, ukdyn::Slot(slot)}, q, M);
            benchmark::DoNotOptimize(M.data());
          }
        });
    benchmark::RegisterBenchmark(
        ("tree/chain_" + std::to_string(n) + "_bias").c_str(), [n](benchmark::State& st) {
          const auto t = chain(n);
          Vec q, qd, c(n), G(n);
          state(n, q, qd);
          std::vector<double> slot(static_cast<std::size_t>(t->slot_size()));
          for (auto _ : st) {
            t->coriolis_times_qd({0.0, ukdyn::Slot(slot)}, q, qd, c);
            t->gravity({0.0, ukdyn::Slot(slot)}, q, G);
            benchmark::DoNotOptimize(c.data());
          }
        });
  }
}

#ifdef UKDYN_BENCH_HAVE_IO
// A state of a scenario with a velocity along its constraints (the null space of A at q0) and a
// nonzero τ, where the derivatives are timed.
struct DerivativeState {
  Vec q, qd, tau;
};

DerivativeState derivative_state(const ukdyn::Scenario& sc) {
  const ukdyn::System& sys = *sc.system;
  const Index n = sys.dof();
  DerivativeState s{sc.q0, sc.qd0, Vec::Zero(n)};
  for (Index i = 0; i < n; ++i) s.tau(i) = 0.3 * std::sin(1.7 * static_cast<double>(i) + 0.4);
  ukdyn::ForwardData d(sys);
  ukdyn::forward(sys, d, sc.sim.t0, s.q, s.qd, s.tau, sc.sim.uk);
  // Without constraint rows every direction is free (Eigen's SVD of a 0 × n matrix is not used).
  Mat V = Mat::Identity(n, n);
  Index rank = 0;
  if (d.A.rows() > 0) {
    Eigen::JacobiSVD<Mat> svd(d.A, Eigen::ComputeFullV);
    V = svd.matrixV();
    while (rank < svd.singularValues().size() && svd.singularValues()(rank) > 1e-9) ++rank;
  }
  for (Index k = rank; k < n; ++k) s.qd += 0.3 * std::cos(1.3 * static_cast<double>(k)) * V.col(k);
  return s;
}

// Skips the case (and says why) when a component of the scenario has no exact derivatives.
bool skip_without_derivatives(const ukdyn::Scenario& sc, benchmark::State& st) {
  if (ukdyn::components_without_derivatives(*sc.system).empty()) return false;
  st.SkipWithError("a component has no exact derivatives");
  return true;
}

// The exact derivatives (linearize(): ∂q̈/∂(q, q̇, τ) and ∂Qc/∂(q, q̇, τ)) against what a user
// without them does: central differences of forward(), 2 calls per column of (q, q̇, τ) (q̈ only).
void register_derivatives(const std::vector<std::pair<std::string, std::string>>& files) {
  for (const auto& [name, path] : files) {
    with_min_max(benchmark::RegisterBenchmark(
        ("derivatives/" + name + "_linearize").c_str(), [path](benchmark::State& st) {
          const ukdyn::Scenario sc = ukdyn::load_scenario(path);
          if (skip_without_derivatives(sc, st)) return;
          const DerivativeState s = derivative_state(sc);
          for (auto _ : st) {
            const ukdyn::Linearization l =
                ukdyn::linearize(*sc.system, sc.sim.t0, s.q, s.qd, s.tau, sc.sim.uk);
            benchmark::DoNotOptimize(l.dqdd_dq.data());
          }
          st.counters["dof"] = static_cast<double>(sc.system->dof());
        }));
    // The same into a LinearizeData kept across calls (no allocation): all parts (∂/∂t included),
    // all parts but the time column (its cost is the difference), or only ∂q̈/∂(q, q̇) (what the
    // implicit integrators' Jacobian takes).
    const std::pair<const char*, ukdyn::LinearizeParts> variants[] = {
        {"_linearize_workspace", {true, true, false, true}},
        {"_linearize_workspace_no_time", {true, true, false, false}},
        {"_linearize_dqdd_dx", {false, false, false, false}}};
    for (const auto& [suffix, parts] : variants) {
      with_min_max(benchmark::RegisterBenchmark(
          ("derivatives/" + name + suffix).c_str(), [path, parts](benchmark::State& st) {
            const ukdyn::Scenario sc = ukdyn::load_scenario(path);
            if (skip_without_derivatives(sc, st)) return;
            const DerivativeState s = derivative_state(sc);
            ukdyn::LinearizeData data(*sc.system);
            for (auto _ : st) {
              ukdyn::linearize(*sc.system, data, sc.sim.t0, s.q, s.qd, s.tau, sc.sim.uk, parts);
              benchmark::DoNotOptimize(data.lin.dqdd_dq.data());
            }
          }));
    }
    // ∂q̈/∂(q, q̇) alone as own blocks plus the coupling through the load
    // (LinearizeParts::structured; the dense matrices where the arrow solve does not run).
    with_min_max(benchmark::RegisterBenchmark(
        ("derivatives/" + name + "_linearize_dqdd_dx_structured").c_str(),
        [path](benchmark::State& st) {
          const ukdyn::Scenario sc = ukdyn::load_scenario(path);
          if (skip_without_derivatives(sc, st)) return;
          const DerivativeState s = derivative_state(sc);
          ukdyn::LinearizeData data(*sc.system);
          const ukdyn::LinearizeParts parts{false, false, true, false};
          for (auto _ : st) {
            ukdyn::linearize(*sc.system, data, sc.sim.t0, s.q, s.qd, s.tau, sc.sim.uk, parts);
            benchmark::DoNotOptimize(data.dqdd_dx.XL.data());
          }
          st.counters["structured"] = data.structured ? 1.0 : 0.0;
        }));
    with_min_max(benchmark::RegisterBenchmark(
        ("derivatives/" + name + "_central_differences").c_str(), [path](benchmark::State& st) {
          const ukdyn::Scenario sc = ukdyn::load_scenario(path);
          const ukdyn::System& sys = *sc.system;
          const Index n = sys.dof();
          const DerivativeState s = derivative_state(sc);
          ukdyn::ForwardData d(sys);
          Mat J(n, 3 * n);
          for (auto _ : st) {
            Vec x[3] = {s.q, s.qd, s.tau};
            for (int which = 0; which < 3; ++which) {
              for (Index j = 0; j < n; ++j) {
                const double v = x[which](j), h = 1e-6 * (1.0 + std::abs(v));
                x[which](j) = v + h;
                ukdyn::forward(sys, d, sc.sim.t0, x[0], x[1], x[2], sc.sim.uk);
                J.col(which * n + j) = d.qdd;
                x[which](j) = v - h;
                ukdyn::forward(sys, d, sc.sim.t0, x[0], x[1], x[2], sc.sim.uk);
                J.col(which * n + j) = (J.col(which * n + j) - d.qdd) / (2 * h);
                x[which](j) = v;
              }
            }
            benchmark::DoNotOptimize(J.data());
          }
        }));
  }
}

// The shipped multi-arm scenarios, one Panda and one iiwa alone (bench/panda_arm.yaml,
// iiwa_arm.yaml: no constraint rows), and the files listed in UKDYN_BENCH_SCENARIOS (paths
// separated by ':'; e.g. tools/n_robots.py 64 --weld > /tmp/n64.yaml for the N-robot scaling).
void register_scenarios() {
  std::vector<std::pair<std::string, std::string>> files;
  for (const std::string name :
       {"paper_chain", "two_ur5e_load", "four_panda_plate", "n_robots_4_weld", "two_pandas_weld"})
    files.emplace_back(name, std::string(UKDYN_BENCH_SOURCE_DIR) + "/scenarios/" + name + ".yaml");
  for (const std::string name : {"panda_arm", "iiwa_arm"})
    files.emplace_back(name, std::string(UKDYN_BENCH_SOURCE_DIR) + "/bench/" + name + ".yaml");
  if (const char* extra = std::getenv("UKDYN_BENCH_SCENARIOS")) {
    std::string list = extra;
    for (std::size_t a = 0; a < list.size();) {
      const std::size_t b = std::min(list.find(':', a), list.size());
      const std::string path = list.substr(a, b - a);
      if (!path.empty()) {
        const std::size_t slash = path.find_last_of('/');
        files.emplace_back(path.substr(slash == std::string::npos ? 0 : slash + 1), path);
      }
      a = b + 1;
    }
  }
  register_derivatives(files);
  for (const auto& [name, path] : files) {
    benchmark::RegisterBenchmark(
        ("scenario/" + name + "_forward").c_str(), [path](benchmark::State& st) {
          const ukdyn::Scenario sc = ukdyn::load_scenario(path);
          const ukdyn::System& sys = *sc.system;
          ukdyn::ForwardData data(sys);
          const Vec tau = Vec::Zero(sys.dof());
          for (auto _ : st) {
            ukdyn::forward(sys, data, sc.sim.t0, sc.q0, sc.qd0, tau, sc.sim.uk);
            benchmark::DoNotOptimize(data.qdd.data());
          }
        });
  }
}
#endif

#ifdef UKDYN_BENCH_HAVE_MUJOCO
// The two-Panda weld system in MuJoCo (tools/two_pandas_weld.py writes it with the scenario).
std::string two_pandas_mjcf() {
  return std::string(UKDYN_BENCH_SOURCE_DIR) + "/bench/two_pandas_weld.xml";
}

struct MjPair {
  mjModel* m = nullptr;
  mjData* d = nullptr;
  std::string error;
  MjPair() {
    char err[1000] = "";
    m = mj_loadXML(two_pandas_mjcf().c_str(), nullptr, err, sizeof err);
    if (m == nullptr) {
      error = err;
      return;
    }
    d = mj_makeData(m);
    const int key = mj_name2id(m, mjOBJ_KEY, "grasp");
    if (key < 0) {
      error = "no keyframe 'grasp'";
      return;
    }
    mj_resetDataKeyframe(m, d, key);
  }
  MjPair(const MjPair&) = delete;
  MjPair& operator=(const MjPair&) = delete;
  ~MjPair() {
    if (d != nullptr) mj_deleteData(d);
    if (m != nullptr) mj_deleteModel(m);
  }
};

// MuJoCo's defaults: Newton solver (mjSOL_NEWTON), 100 iterations, tolerance 1e-8, warm start on
// (each call starts from the previous call's qacc, so at this fixed state the solver stops after
// its first iteration), weld solref (0.02, 1), solimp (0.9, 0.95, 0.001), contacts disabled.
void register_two_pandas_mujoco() {
  with_min_max(
      benchmark::RegisterBenchmark("mujoco/two_pandas_weld_mj_forward", [](benchmark::State& st) {
        MjPair p;
        if (!p.error.empty()) {
          st.SkipWithError(p.error.c_str());
          return;
        }
        for (auto _ : st) {
          mj_forward(p.m, p.d);
          benchmark::DoNotOptimize(p.d->qacc);
          benchmark::ClobberMemory();
        }
        st.counters["nefc"] = p.d->nefc;
        st.counters["solver_iter"] = p.d->solver_iter;
      }));
  // What a MuJoCo user has for derivatives: mjd_transitionFD (finite differences of mj_step,
  // centred, eps 1e-6), the discrete-time A (2nv × 2nv) and B (2nv × nu).
  with_min_max(benchmark::RegisterBenchmark(
      "mujoco/two_pandas_weld_mjd_transitionFD", [](benchmark::State& st) {
        MjPair p;
        if (!p.error.empty()) {
          st.SkipWithError(p.error.c_str());
          return;
        }
        const int nv = p.m->nv, nu = p.m->nu;
        std::vector<mjtNum> A(static_cast<std::size_t>(4 * nv * nv)),
            B(static_cast<std::size_t>(2 * nv * std::max(nu, 1)));
        for (auto _ : st) {
          mjd_transitionFD(p.m, p.d, 1e-6, 1, A.data(), nu > 0 ? B.data() : nullptr, nullptr,
                           nullptr);
          benchmark::DoNotOptimize(A.data());
        }
        st.counters["nv"] = nv;
        st.counters["nu"] = nu;
      }));
}
#endif

#if defined(UKDYN_BENCH_HAVE_MUJOCO) && defined(UKDYN_BENCH_HAVE_IO)
// q̈ of MuJoCo (qacc) and of ukdyn (forward()) at the same state; the load's angular part of
// ukdyn's quaternion rates turned into the body-frame ω̇ MuJoCo uses (q̇ = 0 here: ω̇ = 2 q̄ ⊗ q̈).
struct QddDiff {
  double arms = 0, arms_max = 0, load = 0, load_max = 0;
};

QddDiff qdd_diff(const mjData* d, const Vec& qdd) {
  QddDiff r;
  for (Index i = 0; i < 20; ++i) {
    r.arms = std::max(r.arms, std::abs(d->qacc[i] - qdd[i]));
    r.arms_max = std::max(r.arms_max, std::abs(qdd[i]));
  }
  const Eigen::Quaterniond q(1, 0, 0, 0);
  const Eigen::Quaterniond qdd_q(qdd[23], qdd[24], qdd[25], qdd[26]);
  const Eigen::Vector3d wd = 2.0 * (q.conjugate() * qdd_q).vec();
  for (Index i = 0; i < 6; ++i) {
    const double uk = i < 3 ? qdd[20 + i] : wd[i - 3];
    r.load = std::max(r.load, std::abs(d->qacc[20 + i] - uk));
    r.load_max = std::max(r.load_max, std::abs(uk));
  }
  return r;
}
#endif

}  // namespace

void register_tree_benchmarks() {
  register_robot("panda", 7);
  register_robot("ur5e", 6);
  register_floating("panda", 7);
  register_floating("ur5e", 6);
  register_chains();
#ifdef UKDYN_BENCH_HAVE_IO
  register_scenarios();
#endif
#ifdef UKDYN_BENCH_HAVE_MUJOCO
  register_two_pandas_mujoco();
#endif
}

#if defined(UKDYN_BENCH_HAVE_MUJOCO) && defined(UKDYN_BENCH_HAVE_IO)
void print_two_pandas_weld_check() {
  std::printf(
      "\nTwo Pandas welded to a plate, at the initial state (scenarios/two_pandas_weld.yaml vs\n"
      "bench/two_pandas_weld.xml keyframe 'grasp', q̇ = 0, τ = 0): MuJoCo's qacc vs ukdyn's q̈\n");
  try {
    const ukdyn::Scenario sc = ukdyn::load_scenario(std::string(UKDYN_BENCH_SOURCE_DIR) +
                                                    "/scenarios/two_pandas_weld.yaml");
    const ukdyn::System& sys = *sc.system;
    ukdyn::ForwardData data(sys);
    const Vec tau = Vec::Zero(sys.dof());
    ukdyn::forward(sys, data, sc.sim.t0, sc.q0, sc.qd0, tau, sc.sim.uk);
    Vec phi(sys.rows());
    ukdyn::position_residuals(sys, sc.sim.t0, sc.q0, phi);
    MjPair p;
    if (!p.error.empty() || sys.dof() != 27 || p.m->nq != 27) {
      std::printf("  failed: %s (n = %d, nq = %d)\n", p.error.c_str(), static_cast<int>(sys.dof()),
                  p.m == nullptr ? -1 : p.m->nq);
      return;
    }
    double dq = 0;
    for (Index i = 0; i < 27; ++i) dq = std::max(dq, std::abs(p.d->qpos[i] - sc.q0[i]));
    std::printf("  ukdyn: n = %d, m = %d rows, max |Phi(q0)| = %.1e; |qpos - q0| = %.1e\n",
                static_cast<int>(sys.dof()), static_cast<int>(sys.rows()),
                phi.cwiseAbs().maxCoeff(), dq);
    std::printf("  %-44s %5s %9s %10s %10s %10s %10s\n", "MuJoCo weld solimp (solref 0.02 1)",
                "nefc", "max|pos|", "arms diff", "arms max", "load diff", "load max");
    const double soft[][2] = {{-1, -1}, {0.99, 0.99}, {0.9999, 0.9999}};
    for (const auto& s : soft) {
      if (s[0] > 0)
        for (int e = 0; e < p.m->neq; ++e) {
          p.m->eq_solimp[e * mjNIMP + 0] = s[0];
          p.m->eq_solimp[e * mjNIMP + 1] = s[1];
        }
      mj_resetDataKeyframe(p.m, p.d, 0);
      mj_forward(p.m, p.d);
      double pos = 0;
      for (int i = 0; i < p.d->nefc; ++i) pos = std::max(pos, std::abs(p.d->efc_pos[i]));
      const QddDiff r = qdd_diff(p.d, data.qdd);
      char label[64];
      if (s[0] > 0)
        std::snprintf(label, sizeof label, "%g %g 0.001", s[0], s[1]);
      else
        std::snprintf(label, sizeof label, "0.9 0.95 0.001 (default)");
      std::printf("  %-44s %5d %9.1e %10.2e %10.2e %10.2e %10.2e\n", label, p.d->nefc, pos, r.arms,
                  r.arms_max, r.load, r.load_max);
    }
    std::printf(
        "  (arms: the 20 platform and joint coordinates, rad/s^2 or m/s^2; load: its linear and\n"
        "  body-frame angular acceleration. MuJoCo's welds are soft: its constraint force is\n"
        "  regularised by (1 - d)/d with d = solimp, so q̈ approaches ukdyn's ideal welds as d -> "
        "1.)\n");
  } catch (const std::exception& e) {
    std::printf("  failed: %s\n", e.what());
  }
}
#endif

}  // namespace ukbench
