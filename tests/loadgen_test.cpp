// slamd-load's measurements: URL parsing, percentiles, Prometheus sums, the RSS trend and the
// request mix. The whole tool runs against a real slamd in slamd_http_tests.

#include <gtest/gtest.h>
#include <unistd.h>

#include <vector>

#include "loadgen/measures.hpp"
#include "loadgen/rest_mix.hpp"

namespace slam::loadgen {
namespace {

TEST(LoadgenUrl, HostAndPortFromAnHttpUrl) {
  const auto target = ParseUrl("http://127.0.0.1:8080/");
  ASSERT_TRUE(target.has_value());
  EXPECT_EQ(target->host, "127.0.0.1");
  EXPECT_EQ(target->port, 8080);
  const auto default_port = ParseUrl("http://robot.local/api");
  ASSERT_TRUE(default_port.has_value());
  EXPECT_EQ(default_port->host, "robot.local");
  EXPECT_EQ(default_port->port, 80);
}

TEST(LoadgenUrl, AnythingElseIsRefused) {
  for (const char* bad :
       {"", "127.0.0.1:8080", "https://host:1/", "http://:8080/", "http://host:0/",
        "http://host:65536/", "http://host:80x/", "http://host:/"}) {
    EXPECT_FALSE(ParseUrl(bad).has_value()) << bad;
  }
}

TEST(LoadgenPercentiles, NearestRankOverUnsortedValues) {
  std::vector<double> values;
  for (int i = 100; i >= 1; --i) values.push_back(i);
  const Percentiles p = Summarise(values);
  EXPECT_EQ(p.p50, 50);
  EXPECT_EQ(p.p90, 90);
  EXPECT_EQ(p.p99, 99);
  EXPECT_EQ(p.max, 100);
  const Percentiles one = Summarise({7.5});
  EXPECT_EQ(one.p50, 7.5);
  EXPECT_EQ(one.p99, 7.5);
  const Percentiles none = Summarise({});
  EXPECT_EQ(none.max, 0);
}

TEST(LoadgenRecord, ErrorsAreAnythingButSuccessAndNotModified) {
  Record a;
  a.Add(1.0, 200);
  a.Add(2.0, 304);
  a.Add(3.0, 503);
  Record b;
  b.Add(4.0, 0);  // transport failure
  b.Add(5.0, 204);
  a.Merge(b);
  EXPECT_EQ(a.latencies_ms.size(), 5u);
  EXPECT_EQ(a.errors, 2);
  EXPECT_EQ(a.statuses[200], 1);
  EXPECT_EQ(a.statuses[0], 1);
}

TEST(LoadgenMetrics, SumsEverySampleOfTheNameWithAnyLabelsAndNoOther) {
  const std::string text =
      "# HELP slamd_scans_total Scans processed.\n"
      "# TYPE slamd_scans_total counter\n"
      "slamd_scans_total 120\n"
      "slamd_scans_total_extra 5\n"
      "slamd_late_scans_total{reason=\"budget\"} 2\n"
      "slamd_late_scans_total{reason=\"queue\"} 3\n";
  EXPECT_EQ(MetricValue(text, "slamd_scans_total"), 120.0);
  EXPECT_EQ(MetricValue(text, "slamd_late_scans_total"), 5.0);
  EXPECT_FALSE(MetricValue(text, "slamd_missing").has_value());
}

TEST(LoadgenRss, TrendOverTheSecondHalf) {
  std::vector<std::pair<double, double>> series;
  for (int t = 0; t <= 40; ++t)
    series.emplace_back(t, 100.0 + (t < 20 ? 2.0 * t : 40.0 + 0.5 * (t - 20)));
  const RssTrend trend = Trend(series);
  ASSERT_TRUE(trend.second_half_growth_mib.has_value());
  EXPECT_NEAR(*trend.second_half_growth_mib, 10.0, 1e-9);  // t 20 to 40 at 0.5 MiB/s
  ASSERT_TRUE(trend.second_half_slope_mib_per_min.has_value());
  EXPECT_NEAR(*trend.second_half_slope_mib_per_min, 30.0, 1e-9);
  EXPECT_EQ(trend.every_10_s.size(), 5u);  // t = 0, 10, 20, 30, 40
  EXPECT_FALSE(Trend({{0.0, 1.0}, {1.0, 2.0}}).second_half_growth_mib.has_value());
}

TEST(LoadgenRss, ReadsThisProcessAndNotAMissingOne) {
  const auto own = ReadRssMib(static_cast<int>(::getpid()));
  ASSERT_TRUE(own.has_value());
  EXPECT_GT(*own, 0.0);
  EXPECT_FALSE(ReadRssMib(0x7ffffff0).has_value());
}

TEST(LoadgenMix, APatchEveryFiftiethRequestAndTheFiveGetsInTurn) {
  int patches = 0, tiles = 0;
  for (uint64_t k = 0; k < 1000; ++k) {
    patches += KindOf(k) == RequestKind::kPatchBudget;
    tiles += KindOf(k) == RequestKind::kTile;
  }
  EXPECT_EQ(patches, 20);
  EXPECT_EQ(tiles, 200);
  EXPECT_EQ(KindOf(0), RequestKind::kStatus);
  EXPECT_EQ(KindOf(49), RequestKind::kPatchBudget);
  EXPECT_EQ(KindOf(54), RequestKind::kMetrics);
}

}  // namespace
}  // namespace slam::loadgen
