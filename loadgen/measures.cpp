#include "loadgen/measures.hpp"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <sstream>

namespace slam::loadgen {

double SecondsBetween(Clock::time_point from, Clock::time_point to) {
  return std::chrono::duration<double>(to - from).count();
}

std::optional<Target> ParseUrl(const std::string& url, const std::string& scheme) {
  if (url.compare(0, scheme.size(), scheme) != 0) return std::nullopt;
  const std::string rest = url.substr(scheme.size());
  const size_t slash = rest.find('/');
  const std::string authority = rest.substr(0, slash);
  const size_t colon = authority.rfind(':');
  Target target;
  if (colon == std::string::npos) {
    target.host = authority;
    target.port = 80;
  } else {
    target.host = authority.substr(0, colon);
    char* end = nullptr;
    const long port = std::strtol(authority.c_str() + colon + 1, &end, 10);
    if (end == nullptr || *end != '\0' || port <= 0 || port > 65535) return std::nullopt;
    target.port = static_cast<int>(port);
  }
  if (target.host.empty()) return std::nullopt;
  return target;
}

void Record::Add(double latency_ms, int status) {
  latencies_ms.push_back(latency_ms);
  ++statuses[status];
  const bool ok = (status >= 200 && status < 300) || status == 304;
  if (!ok) ++errors;
}

void Record::Merge(const Record& other) {
  latencies_ms.insert(latencies_ms.end(), other.latencies_ms.begin(), other.latencies_ms.end());
  for (const auto& [status, count] : other.statuses) statuses[status] += count;
  errors += other.errors;
}

Percentiles Summarise(std::vector<double> values) {
  Percentiles result;
  if (values.empty()) return result;
  std::sort(values.begin(), values.end());
  const auto at = [&](double q) {
    const auto rank = static_cast<size_t>(std::ceil(q * static_cast<double>(values.size())));
    return values[std::min(values.size() - 1, rank == 0 ? 0 : rank - 1)];
  };
  result.p50 = at(0.50);
  result.p90 = at(0.90);
  result.p99 = at(0.99);
  result.max = values.back();
  return result;
}

RssTrend Trend(const std::vector<std::pair<double, double>>& series) {
  RssTrend trend;
  double next_mark = 0.0;
  for (const auto& [t, mib] : series) {
    if (t + 0.5 >= next_mark) {
      trend.every_10_s.push_back(std::round(mib * 10.0) / 10.0);
      next_mark += 10.0;
    }
  }
  if (series.size() < 4) return trend;
  const double half = series.back().first / 2.0;
  std::vector<std::pair<double, double>> tail;
  for (const auto& sample : series) {
    if (sample.first >= half) tail.push_back(sample);
  }
  if (tail.size() < 2) return trend;
  trend.second_half_growth_mib = tail.back().second - tail.front().second;
  double mt = 0.0, mm = 0.0;
  for (const auto& [t, mib] : tail) {
    mt += t;
    mm += mib;
  }
  mt /= static_cast<double>(tail.size());
  mm /= static_cast<double>(tail.size());
  double stt = 0.0, stm = 0.0;
  for (const auto& [t, mib] : tail) {
    stt += (t - mt) * (t - mt);
    stm += (t - mt) * (mib - mm);
  }
  if (stt > 0.0) trend.second_half_slope_mib_per_min = stm / stt * 60.0;
  return trend;
}

std::optional<double> MetricValue(const std::string& text, const std::string& name) {
  std::istringstream lines(text);
  std::string line;
  std::optional<double> sum;
  while (std::getline(lines, line)) {
    if (line.empty() || line.front() == '#') continue;
    if (line.compare(0, name.size(), name) != 0) continue;
    if (line.size() <= name.size() || (line[name.size()] != ' ' && line[name.size()] != '{')) {
      continue;
    }
    const size_t value_at = line.rfind(' ');
    sum = sum.value_or(0.0) + std::strtod(line.c_str() + value_at + 1, nullptr);
  }
  return sum;
}

std::optional<double> ReadRssMib(int pid) {
  std::ifstream status("/proc/" + std::to_string(pid) + "/status");
  std::string line;
  while (std::getline(status, line)) {
    if (line.compare(0, 6, "VmRSS:") == 0) {
      return std::strtod(line.c_str() + 6, nullptr) / 1024.0;  // kB -> MiB
    }
  }
  return std::nullopt;
}

}  // namespace slam::loadgen
