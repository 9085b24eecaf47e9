#pragma once
// The command line of slamd and of every tool: CLI11's parse, except that an unknown option is
// answered with the nearest of the program's own options ("slam-replay: unknown option --budgte
// (did you mean --budget?)") rather than CLI11's "The following argument was not expected".
// Header-only, like CLI11, so that each main includes it whatever libraries it links.
//
//   CLI::App app{...};
//   ...
//   if (const std::optional<int> exit_code = slam::cli::Parse(app, argc, argv)) return *exit_code;

#include <CLI/CLI.hpp>
#include <algorithm>
#include <cctype>
#include <cstddef>
#include <filesystem>
#include <iostream>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "engine/io/text_fields.hpp"
#include "engine/pose.hpp"

namespace slam::cli {

/// The optimal string alignment distance between `a` and `b` (insertions, deletions,
/// substitutions and swaps of two adjacent characters count one each), ignoring ASCII case.
inline size_t EditDistance(std::string_view a, std::string_view b) {
  const auto lower = [](char c) {
    return static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  };
  // Three rows of the dynamic programme: i - 2, i - 1 and i.
  std::vector<size_t> before(b.size() + 1), previous(b.size() + 1), current(b.size() + 1);
  for (size_t j = 0; j <= b.size(); ++j) previous[j] = j;
  for (size_t i = 1; i <= a.size(); ++i) {
    current[0] = i;
    for (size_t j = 1; j <= b.size(); ++j) {
      const size_t cost = lower(a[i - 1]) == lower(b[j - 1]) ? 0 : 1;
      current[j] = std::min({previous[j] + 1, current[j - 1] + 1, previous[j - 1] + cost});
      if (i > 1 && j > 1 && lower(a[i - 1]) == lower(b[j - 2]) &&
          lower(a[i - 2]) == lower(b[j - 1])) {
        current[j] = std::min(current[j], before[j - 2] + 1);
      }
    }
    std::swap(before, previous);
    std::swap(previous, current);
  }
  return previous[b.size()];
}

/// `name` without its leading dashes.
inline std::string_view WithoutDashes(std::string_view name) {
  return name.substr(std::min(name.find_first_not_of('-'), name.size()));
}

/// The candidates `typed` is most likely a slip for: those at the smallest edit distance when it
/// is at most a third of the longer name's length without dashes, else the one candidate that
/// `typed` (two characters or more) begins; empty when none is near. Leading dashes count in
/// the distance, so pass names as they are written ("--budget").
inline std::vector<std::string> NearestNames(std::string_view typed,
                                             const std::vector<std::string>& candidates) {
  std::vector<std::string> nearest;
  size_t best = std::string_view::npos;
  for (const std::string& candidate : candidates) {
    if (candidate == typed) continue;
    const size_t distance = EditDistance(typed, candidate);
    const size_t limit = std::max(WithoutDashes(typed).size(), WithoutDashes(candidate).size()) / 3;
    if (distance > limit || distance > best) continue;
    if (distance < best) nearest.clear();
    best = distance;
    if (std::find(nearest.begin(), nearest.end(), candidate) == nearest.end())
      nearest.push_back(candidate);
  }
  if (!nearest.empty()) return nearest;
  if (WithoutDashes(typed).size() < 2) return {};
  for (const std::string& candidate : candidates) {
    if (candidate.size() > typed.size() && candidate.compare(0, typed.size(), typed) == 0)
      nearest.push_back(candidate);
  }
  if (nearest.size() != 1) return {};
  return nearest;
}

/// "(did you mean --a?)", "(did you mean --a or --b?)"; "" for no name.
inline std::string DidYouMean(const std::vector<std::string>& names) {
  if (names.empty()) return "";
  std::string text = "(did you mean ";
  for (size_t i = 0; i < names.size(); ++i) {
    if (i > 0) text += i + 1 == names.size() ? " or " : ", ";
    text += names[i];
  }
  return text + "?)";
}

/// Every name of `app`'s options ("--budget", "-h"), and of the subcommands it parsed.
inline std::vector<std::string> OptionNames(const CLI::App& app) {
  std::vector<std::string> names;
  for (const CLI::Option* option : app.get_options()) {
    for (const std::string& name : option->get_lnames()) names.push_back("--" + name);
    for (const std::string& name : option->get_snames()) names.push_back("-" + name);
  }
  for (const CLI::App* sub : app.get_subcommands()) {
    const std::vector<std::string> more = OptionNames(*sub);
    names.insert(names.end(), more.begin(), more.end());
  }
  return names;
}

/// One line per argument of the command line that `app` did not take (after a parse that threw):
/// "unknown option --budgte (did you mean --budget?)" for those that look like options,
/// "unknown command datset (did you mean dataset?)" for a word near a subcommand's name. Empty
/// when no option is unknown (other words alone are left to CLI11's own message).
inline std::vector<std::string> UnknownArgumentMessages(const CLI::App& app) {
  const std::vector<std::string> extras = app.remaining(true);
  const std::vector<std::string> options = OptionNames(app);
  std::vector<std::string> subcommands;
  for (const CLI::App* sub : app.get_subcommands({})) subcommands.push_back(sub->get_name());
  std::vector<std::string> lines;
  bool any_option = false;
  for (const std::string& extra : extras) {
    // A lone "-" or a negative number is a value, not an option.
    const bool option = extra.size() > 1 && extra[0] == '-' &&
                        !(std::isdigit(static_cast<unsigned char>(extra[1])) || extra[1] == '.');
    if (option) {
      any_option = true;
      const std::string name = extra.substr(0, extra.find('='));
      const std::string hint = DidYouMean(NearestNames(name, options));
      lines.push_back("unknown option " + name + (hint.empty() ? "" : " " + hint));
    } else if (!subcommands.empty()) {
      const std::string hint = DidYouMean(NearestNames(extra, subcommands));
      if (!hint.empty()) lines.push_back("unknown command " + extra + " " + hint);
    }
  }
  if (!any_option && lines.empty()) return {};
  return lines;
}

/// Reports a parse error as CLI11's app.exit does (help and version on stdout with status 0),
/// except that unknown options, the usual cause of any error when there are some (a mistyped
/// required option is also "required"), are named with the nearest known ones; returns the
/// exit status.
inline int ReportParseError(const CLI::App& app, const CLI::ParseError& error) {
  if (error.get_exit_code() == static_cast<int>(CLI::ExitCodes::Success)) {
    return app.exit(error);
  }
  const std::vector<std::string> lines = UnknownArgumentMessages(app);
  if (lines.empty()) return app.exit(error);
  const std::string program = std::filesystem::path(app.get_name()).filename().string();
  for (const std::string& line : lines) std::cerr << program << ": " << line << "\n";
  std::cerr << "Run with --help for more information.\n";
  return static_cast<int>(CLI::ExitCodes::ExtrasError);
}

/// Parses the command line into `app`: nullopt to go on, else the exit status to return after
/// --help, --version or an error (reported by ReportParseError).
inline std::optional<int> Parse(CLI::App& app, int argc, const char* const* argv) {
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& error) {
    return ReportParseError(app, error);
  }
  return std::nullopt;
}

/// `text` as a whole finite number ("0.5", "-1e-3"), nullopt otherwise ("", "1x", "nan", "inf"):
/// io::ParseFiniteDouble, as the logs' fields are read.
inline std::optional<double> FiniteNumber(std::string_view text) {
  double value = 0.0;
  if (!io::ParseFiniteDouble(text, value)) return std::nullopt;
  return value;
}

/// The `count` finite numbers of `text` separated by `separator` ("1,2,3"); nullopt when there
/// are more or fewer, or one is not a finite number (an empty field included).
inline std::optional<std::vector<double>> FiniteNumbers(std::string_view text, char separator,
                                                        size_t count) {
  std::vector<double> values;
  for (size_t from = 0; from <= text.size();) {
    const size_t end = std::min(text.find(separator, from), text.size());
    const std::optional<double> value = FiniteNumber(text.substr(from, end - from));
    if (!value || values.size() == count) return std::nullopt;
    values.push_back(*value);
    from = end + 1;
  }
  if (values.size() != count) return std::nullopt;
  return values;
}

/// A pose typed as "X,Y,THETA_DEG" (metres, metres, degrees), the heading normalised to
/// (-pi, pi]; nullopt unless it is three finite numbers.
inline std::optional<Pose2> PoseArgument(std::string_view text) {
  const std::optional<std::vector<double>> v = FiniteNumbers(text, ',', 3);
  if (!v) return std::nullopt;
  return Pose2{(*v)[0], (*v)[1], NormalizeAngle(DegToRad((*v)[2]))};
}

}  // namespace slam::cli
