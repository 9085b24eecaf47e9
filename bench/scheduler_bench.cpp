// Scheduler benchmarks: splitting a quota into a plan, the online scheduler's Plan + Record
// cycle under each policy and quota mode, and one tuner fitness evaluation.
#include <benchmark/benchmark.h>

#include <algorithm>
#include <cstdint>
#include <vector>

#include "bench/bench_support.hpp"
#include "engine/slam.hpp"
#include "offline/tuner.hpp"
#include "scheduler/fixed_plan.hpp"
#include "scheduler/ray_budget_scheduler.hpp"

namespace slam::bench {
namespace {

/// What the scans of the 120 s rooms run offer, as the engine summarises them.
const std::vector<ScanSummary>& Summaries() {
  static const std::vector<ScanSummary> summaries = [] {
    const Slam engine(ShippedRobot(), SlamParams{}, BenchConfig(false));
    std::vector<ScanSummary> out;
    for (const Scan& scan : RoomsRun(120.0).scans) out.push_back(engine.Summarize(scan));
    return out;
  }();
  return summaries;
}

// FixedPlan (SplitQuota) of every scan of the run at budget range(0) with range(1) particles.
// Items are plans.
void BM_FixedPlan(benchmark::State& state) {
  const std::vector<ScanSummary>& summaries = Summaries();
  const SlamParams params = ParamsWith(static_cast<int>(state.range(1)));
  size_t i = 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(FixedPlan(summaries[i++ % summaries.size()], state.range(0), params));
  }
  Items(state, state.iterations(), "plans");
}
BENCHMARK(BM_FixedPlan)->ArgNames({"budget", "particles"})->ArgsProduct({{8125, 65000}, {1, 5}});

// The scheduler's cycle per scan: Plan before it, Record after it (with a report as the engine
// would give for that plan), policy range(0) (0 fixed, 1 adaptive) and quota mode range(1)
// (0 rays per scan, 1 CPU share). Items are scans planned.
void BM_SchedulerPlan(benchmark::State& state) {
  const std::vector<ScanSummary>& summaries = Summaries();
  BudgetSettings settings;
  settings.policy = state.range(0) == 0 ? BudgetPolicy::kFixed : BudgetPolicy::kAdaptive;
  settings.mode = state.range(1) == 0 ? QuotaMode::kRaysPerScan : QuotaMode::kCpuShare;
  settings.rays_per_scan = 65000;
  RayBudgetScheduler scheduler(settings);
  const SlamParams params = ParamsWith(2);
  size_t i = 0;
  for (auto _ : state) {
    const ScanSummary& summary = summaries[i % summaries.size()];
    const ScanPlan plan = scheduler.Plan(summary, 1.0 / 1.5, params);
    ScanReport report;
    report.scan = static_cast<int64_t>(i);
    report.particles = plan.particles;
    report.candidates = plan.candidates;
    report.matching_measurements =
        std::min(plan.matching_measurements,
                 std::max(summary.matching_measurements, summary.matching_available));
    report.update_rays = std::min(plan.update_rays, summary.usable_measurements);
    report.rays.matching = int64_t{plan.particles} * plan.candidates * report.matching_measurements;
    report.rays.update = int64_t{plan.particles} * report.update_rays;
    report.effective_sample_size = plan.particles * ((i & 1) != 0 ? 0.9 : 0.3);
    report.refinement_ambiguity = (i % 3 == 0) ? 0.6 : 0.1;
    benchmark::DoNotOptimize(scheduler.Record(report, 0.004));
    ++i;
  }
  Items(state, state.iterations(), "scans");
}
BENCHMARK(BM_SchedulerPlan)->ArgNames({"adaptive", "cpu_share"})->ArgsProduct({{0, 1}, {0, 1}});

// One fitness evaluation of the tuner (Table II defaults): the rooms run of range(0) seconds
// replayed at budget range(1) on this thread, scored against its ground truth, as each
// individual of the evolution strategy is. Items are scans.
void BM_TunerFitness(benchmark::State& state) {
  const SimulatedRun& run = RoomsRun(static_cast<double>(state.range(0)));
  const std::vector<offline::TuningExperiment> experiments{
      offline::TuningExperiment{run.name, &ShippedRobot(), &run.scans, &run.ground_truth}};
  offline::TuningSettings settings;
  double fitness = 0.0;
  for (auto _ : state) {
    fitness = offline::Fitness(experiments, settings.start, state.range(1), settings);
    benchmark::DoNotOptimize(fitness);
  }
  Items(state, state.iterations() * static_cast<int64_t>(run.scans.size()), "scans");
  state.counters["fitness"] = fitness;
  state.counters["duration_s"] = run.duration_s;
}
BENCHMARK(BM_TunerFitness)
    ->ArgNames({"seconds", "budget"})
    ->Args({30, 8125})
    ->Args({300, 8125})
    ->Args({300, 65000})
    ->Iterations(1)
    ->UseRealTime()
    ->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace slam::bench

BENCHMARK_MAIN();
