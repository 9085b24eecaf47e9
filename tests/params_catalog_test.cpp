// The shipped parameter sets (config/params/<budget>.json, compiled in) and how a quota picks one.
#include "scheduler/params_catalog.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <set>
#include <string>
#include <tuple>

#include "engine/io/params_json.hpp"

namespace slam {
namespace {

namespace fs = std::filesystem;
const fs::path kParamsDir = fs::path(SLAM_SOURCE_DIR) / "config" / "params";

TEST(ParamsCatalogTest, EveryShippedFileIsCompiledInAndValid) {
  for (const auto& [family, dir, prefix] :
       {std::tuple{ParamsFamily::kInfrared, kParamsDir, "shipped-"},
        std::tuple{ParamsFamily::kRange, kParamsDir / "laser", "shipped-laser-"}}) {
    SCOPED_TRACE(dir.string());
    std::set<int64_t> on_disk;
    for (const fs::directory_entry& entry : fs::directory_iterator(dir)) {
      if (entry.is_directory()) continue;  // config/params/laser
      SCOPED_TRACE(entry.path().string());
      ASSERT_EQ(entry.path().extension(), ".json");
      const int64_t budget = std::stoll(entry.path().stem().string());
      on_disk.insert(budget);
      const Result<SlamParams> loaded = io::LoadParams(entry.path().string());
      ASSERT_TRUE(loaded.ok()) << loaded.Message();
      bool found = false;
      for (const ParamsSet& set : ShippedParams(family)) {
        if (set.budget != budget) continue;
        found = true;
        EXPECT_EQ(set.params, loaded.value()) << "rebuild: the compiled-in copy is stale";
        EXPECT_EQ(set.name, prefix + std::to_string(budget));
        EXPECT_TRUE(Validate(set.params).empty());
      }
      EXPECT_TRUE(found);
    }
    EXPECT_EQ(on_disk.size(), ShippedParams(family).size());
    // One set per paper budget, by increasing budget.
    EXPECT_EQ(on_disk, (std::set<int64_t>{8125, 16250, 32500, 65000}));
    for (size_t i = 1; i < ShippedParams(family).size(); ++i)
      EXPECT_LT(ShippedParams(family)[i - 1].budget, ShippedParams(family)[i].budget);
  }
  // The families differ: each was tuned for its scanner.
  EXPECT_NE(ShippedParamsFor(8125, ParamsFamily::kRange).params, ShippedParamsFor(8125).params);
}

TEST(ParamsCatalogTest, AQuotaTakesTheLargestBudgetNotAboveIt) {
  EXPECT_EQ(ShippedParamsFor(1).budget, 8125);  // below every budget: the smallest
  EXPECT_EQ(ShippedParamsFor(8124).budget, 8125);
  EXPECT_EQ(ShippedParamsFor(8125).budget, 8125);
  EXPECT_EQ(ShippedParamsFor(16249).budget, 8125);
  EXPECT_EQ(ShippedParamsFor(16250).budget, 16250);
  EXPECT_EQ(ShippedParamsFor(20000).budget, 16250);
  EXPECT_EQ(ShippedParamsFor(32500).budget, 32500);
  EXPECT_EQ(ShippedParamsFor(64999).budget, 32500);
  EXPECT_EQ(ShippedParamsFor(65000).budget, 65000);
  EXPECT_EQ(ShippedParamsFor(20'000'000).budget, 65000);
  EXPECT_EQ(ShippedParamsFor(20000, ParamsFamily::kRange).budget, 16250);
  EXPECT_EQ(ShippedParamsFor(1, ParamsFamily::kRange).name, "shipped-laser-8125");
}

TEST(ParamsCatalogTest, AGivenSetHoldsWhateverTheQuota) {
  const ParamsChoice shipped;
  EXPECT_TRUE(shipped.follows_quota());
  EXPECT_EQ(&shipped.For(16250), &ShippedParamsFor(16250));
  EXPECT_EQ(shipped.For(70000).name, "shipped-65000");
  EXPECT_EQ(ParamsChoice(ParamsFamily::kRange).For(70000).name, "shipped-laser-65000");

  SlamParams mine;
  mine.particles = 7;
  const ParamsChoice given("my.json", mine);
  EXPECT_FALSE(given.follows_quota());
  for (int64_t quota : {1, 8125, 65000, 1'000'000}) {
    EXPECT_EQ(given.For(quota).name, "my.json");
    EXPECT_EQ(given.For(quota).params.particles, 7);
    EXPECT_EQ(given.For(quota).budget, 0);
  }
}

}  // namespace
}  // namespace slam
