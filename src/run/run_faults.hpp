// Internal to ukdyn::io, for ukdyn's own tests: run_scenario() with write failures injected into its
// output folder (src/output/write_faults.hpp; tests/test_output_safety.cpp, InjectedFailure). Not
// installed: the public RunOptions carries no test hook.
#pragma once

#include <filesystem>

#include "output/write_faults.hpp"
#include "ukdyn/run/run.hpp"

namespace ukdyn::io_detail {

/// run_scenario(scenario, out_dir, options), with the writes into out_dir that `write_failure`
/// chooses failing as on a full disk. With an empty hook it is run_scenario() itself.
RunReport run_scenario_with_write_failures(const Scenario& scenario,
                                           const std::filesystem::path& out_dir,
                                           const RunOptions& options,
                                           WriteFailureHook write_failure);

}  // namespace ukdyn::io_detail
