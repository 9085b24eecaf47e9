#pragma once
// Short simulated experiments for the suites that replay them (link with hw_link and sim).

#include <gtest/gtest.h>

#include <string>

#include "offline/experiment_reader.hpp"
#include "sim/experiment_writer.hpp"
#include "sim/scenario.hpp"
#include "tests/test_support.hpp"

namespace slam::testing {

/// Writes a `duration_s` experiment of the shipped robot in a built-in arena into `dir` and
/// reads it back; records a test failure and returns nothing when either step fails.
inline std::optional<offline::Experiment> GenerateExperiment(const std::string& dir,
                                                             const std::string& arena,
                                                             double duration_s, uint64_t seed) {
  sim::ScenarioConfig config;
  config.duration_s = duration_s;
  config.seed = seed;
  if (const Result<void> written = sim::WriteSimulatedExperiment(dir, *sim::BuiltinWorld(arena),
                                                                 arena, ShippedRobot(), config);
      !written.ok()) {
    ADD_FAILURE() << written.Message();
    return std::nullopt;
  }
  Result<offline::Experiment> load = offline::LoadExperiment(dir);
  if (!load.ok()) {
    ADD_FAILURE() << load.Message();
    return std::nullopt;
  }
  return std::move(load).value();
}

}  // namespace slam::testing
