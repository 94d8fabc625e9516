// MuJoCo side by side: the same mechanism as an MJCF (bench/paper_mechanism.xml), timed with
// mj_forward and mj_step, and the constraint violation it holds over 4 s of free motion.
#include <benchmark/benchmark.h>
#include <mujoco/mujoco.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <memory>
#include <string>
#include <vector>

#include "bench_common.hpp"
#include "paper_model.hpp"

#ifndef UKDYN_BENCH_MJCF
#error "UKDYN_BENCH_MJCF (path of bench/paper_mechanism.xml) must be defined by CMake"
#endif

namespace ukbench {
namespace {

using ukdyn::Vec;

struct ModelDeleter {
  void operator()(mjModel* m) const { mj_deleteModel(m); }
};
struct DataDeleter {
  void operator()(mjData* d) const { mj_deleteData(d); }
};
using ModelPtr = std::unique_ptr<mjModel, ModelDeleter>;
using DataPtr = std::unique_ptr<mjData, DataDeleter>;

/// Address of each paper coordinate in qpos / qvel: per robot x, y, yaw, pitch1..3.
struct JointMap {
  std::array<int, 12> qpos{};
  std::array<int, 12> dof{};
};

const char* const kJointNames[12] = {"r1_x",      "r1_y",      "r1_yaw",    "r1_pitch1",
                                     "r1_pitch2", "r1_pitch3", "r2_x",      "r2_y",
                                     "r2_yaw",    "r2_pitch1", "r2_pitch2", "r2_pitch3"};

struct MjSetup {
  ModelPtr model;
  JointMap map;
  int site1 = -1, site2 = -1;
  std::string error;
};

MjSetup load_model() {
  MjSetup s;
  char err[1024] = "";
  s.model.reset(mj_loadXML(UKDYN_BENCH_MJCF, nullptr, err, sizeof err));
  if (!s.model) {
    s.error = std::string("cannot load ") + UKDYN_BENCH_MJCF + ": " + err;
    return s;
  }
  for (std::size_t i = 0; i < 12; ++i) {
    const int j = mj_name2id(s.model.get(), mjOBJ_JOINT, kJointNames[i]);
    if (j < 0) {
      s.error = std::string("joint ") + kJointNames[i] + " missing in the MJCF";
      s.model.reset();
      return s;
    }
    s.map.qpos[i] = s.model->jnt_qposadr[j];
    s.map.dof[i] = s.model->jnt_dofadr[j];
  }
  s.site1 = mj_name2id(s.model.get(), mjOBJ_SITE, "cut1");
  s.site2 = mj_name2id(s.model.get(), mjOBJ_SITE, "cut2");
  if (s.site1 < 0 || s.site2 < 0) {
    s.error = "sites cut1/cut2 missing in the MJCF";
    s.model.reset();
  }
  return s;
}

const MjSetup& setup() {
  static const MjSetup s = load_model();
  return s;
}

/// Paper coordinates (absolute pitch angles) -> MuJoCo (relative hinges); linear, so also for
/// rates.
void paper_to_mujoco(const Vec& q, const std::array<int, 12>& adr, mjtNum* out) {
  for (int r = 0; r < 2; ++r) {
    const int o = 6 * r;
    const auto i = [&](int k) { return static_cast<std::size_t>(o + k); };
    out[adr[i(0)]] = q[o + 0];
    out[adr[i(1)]] = q[o + 1];
    out[adr[i(2)]] = q[o + 2];
    out[adr[i(3)]] = q[o + 3];
    out[adr[i(4)]] = q[o + 4] - q[o + 3];
    out[adr[i(5)]] = q[o + 5] - q[o + 4];
  }
}

Vec mujoco_to_paper(const mjtNum* in, const std::array<int, 12>& adr) {
  Vec q(12);
  for (int r = 0; r < 2; ++r) {
    const int o = 6 * r;
    const auto i = [&](int k) { return static_cast<std::size_t>(o + k); };
    q[o + 0] = in[adr[i(0)]];
    q[o + 1] = in[adr[i(1)]];
    q[o + 2] = in[adr[i(2)]];
    q[o + 3] = in[adr[i(3)]];
    q[o + 4] = q[o + 3] + in[adr[i(4)]];
    q[o + 5] = q[o + 4] + in[adr[i(5)]];
  }
  return q;
}

void set_initial_state(const MjSetup& s, mjData* d, bool spatial) {
  const PaperModel& pm = paper_model();
  mj_resetData(s.model.get(), d);
  paper_to_mujoco(pm.q0, s.map.qpos, d->qpos);
  paper_to_mujoco(spatial ? pm.qd0_spatial : pm.qd0_zero, s.map.dof, d->qvel);
  d->time = 0.0;
}

/// A copy of the model with another integrator and, optionally, stiffer equality constraints.
ModelPtr variant(const MjSetup& s, int integrator, bool stiff) {
  ModelPtr m(mj_copyModel(nullptr, s.model.get()));
  m->opt.integrator = integrator;
  if (stiff) {
    for (int e = 0; e < m->neq; ++e) {
      m->eq_solref[e * mjNREF + 0] =
          2 * m->opt.timestep;  // the smallest time constant MuJoCo accepts
      m->eq_solref[e * mjNREF + 1] = 1.0;
      m->eq_solimp[e * mjNIMP + 0] = 0.99;
      m->eq_solimp[e * mjNIMP + 1] = 0.999;
    }
  }
  return m;
}

double cut_gap(const MjSetup& s, const mjData* d) {
  double sq = 0;
  for (int k = 0; k < 3; ++k) {
    const double e = d->site_xpos[3 * s.site1 + k] - d->site_xpos[3 * s.site2 + k];
    sq += e * e;
  }
  return std::sqrt(sq);
}

void bm_mj_forward(benchmark::State& state) {
  const MjSetup& s = setup();
  DataPtr d(mj_makeData(s.model.get()));
  set_initial_state(s, d.get(), true);
  for (auto _ : state) {
    mj_forward(s.model.get(), d.get());
    benchmark::DoNotOptimize(d->qacc);
    benchmark::ClobberMemory();
  }
  state.counters["nefc"] = d->nefc;
}

void bm_mj_step(benchmark::State& state, int integrator) {
  const MjSetup& s = setup();
  ModelPtr m = variant(s, integrator, false);
  DataPtr d(mj_makeData(m.get()));
  set_initial_state(s, d.get(), true);
  std::vector<mjtNum> qpos(d->qpos, d->qpos + m->nq), qvel(d->qvel, d->qvel + m->nv);
  int n = 0;
  for (auto _ : state) {
    mj_step(m.get(), d.get());
    if (++n == 4000) {  // restart the 4 s free motion (cheap, amortised over 4000 steps)
      n = 0;
      std::copy(qpos.begin(), qpos.end(), d->qpos);
      std::copy(qvel.begin(), qvel.end(), d->qvel);
      d->time = 0.0;
    }
    benchmark::DoNotOptimize(d->qpos);
    benchmark::ClobberMemory();
  }
}

}  // namespace

bool register_mujoco_benchmarks() {
  const MjSetup& s = setup();
  if (!s.model) {
    std::fprintf(stderr, "ukdyn_bench: MuJoCo part skipped: %s\n", s.error.c_str());
    return false;
  }
  with_min_max(benchmark::RegisterBenchmark("mujoco/mj_forward", bm_mj_forward))
      ->Unit(benchmark::kNanosecond);
  with_min_max(benchmark::RegisterBenchmark("mujoco/mj_step_euler", bm_mj_step, int{mjINT_EULER}))
      ->Unit(benchmark::kNanosecond);
  with_min_max(benchmark::RegisterBenchmark("mujoco/mj_step_rk4", bm_mj_step, int{mjINT_RK4}))
      ->Unit(benchmark::kNanosecond);
  return true;
}

std::vector<ViolationRow> mujoco_violation_rows(bool spatial, const std::vector<double>& q_ref_05) {
  std::vector<ViolationRow> rows;
  const MjSetup& s = setup();
  if (!s.model) return rows;
  const PaperModel& pm = paper_model();
  const std::string start = spatial ? "spatial qd0" : "qd0 = 0";
  constexpr int kSteps = 4000;  // 4 s at dt = 1e-3

  struct Config {
    int integrator;
    bool stiff;
    const char* name;
  };
  const Config configs[] = {{mjINT_EULER, false, "Euler dt 1e-3, default solref"},
                            {mjINT_RK4, false, "RK4 dt 1e-3, default solref"},
                            {mjINT_RK4, true, "RK4 dt 1e-3, stiff solref 0.002/solimp .99"}};
  Vec phi(pm.closure.rows());
  for (const Config& c : configs) {
    ModelPtr m = variant(s, c.integrator, c.stiff);
    DataPtr d(mj_makeData(m.get()));
    ViolationRow row{"MuJoCo " + std::string(mj_versionString()), c.name, start, 0, 0, 0, -1};

    set_initial_state(s, d.get(), spatial);
    for (int k = 0; k <= kSteps; ++k) {
      mj_kinematics(m.get(), d.get());
      row.max_gap = std::max(row.max_gap, cut_gap(s, d.get()));
      const Vec q = mujoco_to_paper(d->qpos, s.map.qpos);
      ukdyn::position_residuals(pm.closure, d->time, q, phi);
      row.max_phi = std::max(row.max_phi, max_abs(phi));
      if (k == 500 && q_ref_05.size() == 12) {
        double dq = 0;
        for (int i = 0; i < 12; ++i)
          dq = std::max(dq, std::abs(q[i] - q_ref_05[static_cast<std::size_t>(i)]));
        row.q_diff = dq;
      }
      if (k < kSteps) mj_step(m.get(), d.get());
    }

    std::vector<double> ms;
    for (int rep = 0; rep < 3; ++rep) {
      set_initial_state(s, d.get(), spatial);
      const auto t0 = std::chrono::steady_clock::now();
      for (int k = 0; k < kSteps; ++k) mj_step(m.get(), d.get());
      const auto t1 = std::chrono::steady_clock::now();
      ms.push_back(std::chrono::duration<double, std::milli>(t1 - t0).count());
    }
    std::sort(ms.begin(), ms.end());
    row.wall_ms = ms[1];
    rows.push_back(row);
  }
  return rows;
}

}  // namespace ukbench
