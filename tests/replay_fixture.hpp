#pragma once
// The fixture of the replay suites (replay_test.cpp, replay_cli_test.cpp): a box and a rooms
// run generated once per suite, and a replay of one with the table-II parameters.

#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "offline/replay.hpp"
#include "tests/experiment_support.hpp"

namespace slam {

/// Experiments generated once for the whole suite: a 40 s run in two arenas.
class ReplayTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    root_ = std::filesystem::path(::testing::TempDir()) /
            ("slam_replay_test_" + std::to_string(::getpid()));
    std::filesystem::remove_all(root_);
    uint64_t seed = 1;
    for (const char* arena : {"box", "rooms"}) {
      auto experiment = testing::GenerateExperiment((root_ / arena).string(), arena, 40.0, seed++);
      ASSERT_TRUE(experiment.has_value());
      experiments_->push_back(std::move(*experiment));
    }
  }
  static void TearDownTestSuite() {
    std::filesystem::remove_all(root_);
    experiments_->clear();
  }

  static const offline::Experiment& Box() { return experiments_->at(0); }

  static offline::ReplayResult Run(const offline::Experiment& e, int64_t budget, bool refine,
                                   uint64_t seed, bool parallel, int particles = 1) {
    offline::ReplayOptions options;
    options.budget.rays_per_scan = budget;
    options.refine = refine;
    options.config.seed = seed;
    options.config.parallel = parallel;
    SlamParams params;
    params.particles = particles;
    options.params = ParamsChoice("table-ii", params);
    return offline::Replay(e.robot, e.scans, e.ground_truth, options);
  }

  static inline std::filesystem::path root_;
  static inline std::vector<offline::Experiment>* experiments_ =
      new std::vector<offline::Experiment>();
};

}  // namespace slam
