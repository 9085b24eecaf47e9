#pragma once
// What slam-tune writes about a tuning study, and reads back to resume it: results.json (per
// budget and generation the fitness quartiles, the best parameters, the last generation's
// fitness values and population), table2.md (best parameters per budget, like the paper's
// Table II), table3.md (two-sided Mann-Whitney U p-values between the budgets' last generations,
// like Table III), fig10.svg and fig10.png (median and interquartile band per generation), and
// params/<budget>.json (the best parameters, for slam-replay and slam-evaluate --params).

#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "engine/result.hpp"
#include "offline/tuner.hpp"

namespace slam::offline {

/// The whole state as results.json holds it.
nlohmann::json TuningStateToJson(const TuningState& state);

/// Reads results.json back (for resuming); every error names what is wrong.
Result<TuningState> TuningStateFromJson(const nlohmann::json& json);

/// Why a saved state cannot be continued with `settings` over `experiments` (empty when it can).
/// The number of generations may differ: a study can be extended.
std::vector<std::string> ResumeConflicts(const TuningState& saved, const TuningSettings& settings,
                                         const std::vector<std::string>& experiments);

/// Table II: the best parameters of every budget, with the defaults for reference.
std::string Table2Markdown(const TuningState& state);

/// Table III: two-sided Mann-Whitney U p-values between the last generations' fitness values of
/// every pair of budgets.
std::string Table3Markdown(const TuningState& state);

/// Writes every output file into `dir` (each atomically); returns the files that failed.
std::vector<std::string> WriteTuningOutputs(const std::string& dir, const TuningState& state);

}  // namespace slam::offline
