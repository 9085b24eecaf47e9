// Fuzzes the saved-state loader: the tile file decoder (server/state_store), the TUM trajectory
// parser and LoadState on a directory whose state.json is the input. The first byte picks:
//   0: the rest as a tile file's body, given its magic and a valid checksum (so the decoder's
//      checks past the checksum are reached);  1: the rest as a whole tile file;
//   2: the rest as TUM text;                     3: the rest as state.json beside valid files.
// Invariants: nothing crashes or allocates without bound; a decoded tile file encodes back to
// the same bytes, its tiles lie within the map's bound, once each, with cells within the limit,
// and it restores into a grid as slamd does; a parsed trajectory is finite, time-ordered and
// formats and parses back to as many poses; LoadState gives a state, nothing, or an error with a
// reason.

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <set>
#include <string>
#include <system_error>
#include <utility>

#include "engine/cell_encoding.hpp"
#include "engine/io/tum.hpp"
#include "engine/occupancy_grid.hpp"
#include "fuzz/fuzz_check.hpp"
#include "server/state_store.hpp"

using slam::fuzz::Check;
using namespace slam;
using namespace slam::server;

namespace {

constexpr char kMagic[] = "SLMTILE1";

void CheckDecoded(const std::string& bytes) {
  Result<SavedState> decoded = DecodeTiles(bytes);
  if (!decoded.ok()) {
    const std::string error = decoded.Message();
    Check(!error.empty(), "DecodeTiles failed without a reason");
    Check(error.find('\n') == std::string::npos, "a decoding error spans lines");
    return;
  }
  const SavedState state = std::move(decoded).value();
  Check(EncodeTiles(state) == bytes, "a decoded tile file does not encode back to its bytes");
  std::set<std::pair<int32_t, int32_t>> seen;
  OccupancyGrid grid(GridGeometry(0.01), kLogOddsLimit);
  grid.BeginWrite();
  for (const SavedTile& tile : state.tiles) {
    Check(InMapBound(tile.index), "a decoded tile lies outside the map's bound");
    Check(seen.insert({tile.index.x, tile.index.y}).second, "a decoded tile appears twice");
    Check(tile.cells.size() == static_cast<size_t>(kTileCells), "a decoded tile's size is wrong");
    for (const LogOdds cell : tile.cells) {
      Check(cell >= -kLogOddsLimit && cell <= kLogOddsLimit, "a decoded cell is beyond the limit");
    }
    // As SlamService::BuildEngine restores a resumed map.
    std::copy(tile.cells.begin(), tile.cells.end(), grid.MutableTile(tile.index).cells.begin());
  }
  Check(grid.Tiles().size() == state.tiles.size(), "the restored grid's tile count differs");
}

void CheckTum(const std::string& text) {
  auto parsed = io::ParseTum(text, "fuzz.tum");
  if (!parsed.ok()) {
    Check(!parsed.Message().empty(), "ParseTum failed without a reason");
    return;
  }
  const auto& poses = parsed.value();
  for (size_t i = 0; i < poses.size(); ++i) {
    const TimedPose& p = poses[i];
    Check(std::isfinite(p.t) && std::isfinite(p.pose.x) && std::isfinite(p.pose.y) &&
              std::isfinite(p.pose.theta),
          "a parsed pose is not finite");
    Check(i == 0 || poses[i - 1].t < p.t, "parsed times are not strictly increasing");
  }
  // Within a bound (the map's at 1 cm cells, as LoadState gives it): accepted exactly when every
  // pose is inside, and then the same poses.
  const io::PositionBound bound{-81.92, 81.92, "the map's bound"};
  bool inside = true;
  for (const TimedPose& p : poses) {
    inside = inside && p.pose.x >= bound.lo_m && p.pose.x < bound.hi_m && p.pose.y >= bound.lo_m &&
             p.pose.y < bound.hi_m;
  }
  const auto bounded = io::ParseTum(text, "fuzz.tum", bound);
  Check(bounded.ok() == inside, "ParseTum's bound accepts a pose outside or refuses one inside");
  if (bounded.ok()) Check(bounded.value().size() == poses.size(), "bounded parse lost poses");
  // Formatting rounds to microseconds, which may merge times closer than that: only count.
  auto again = io::ParseTum(io::FormatTum(poses), "again.tum");
  if (again.ok()) {
    Check(again.value().size() == poses.size(), "a formatted trajectory parses to another size");
  }
}

/// A state directory with valid tiles and trajectory files; state.json is rewritten per input.
const std::filesystem::path& StateDir() {
  static const std::filesystem::path dir = [] {
    const char* shm = "/dev/shm";
    std::filesystem::path base = std::filesystem::exists(shm) ? shm : "/tmp";
    base /= "fuzz_state." + std::to_string(::getpid());
    std::filesystem::create_directories(base);
    static std::filesystem::path cleanup = base;
    std::atexit([] {
      std::error_code ec;
      std::filesystem::remove_all(cleanup, ec);
    });
    SavedState state;
    state.version = 3;
    SavedTile tile;
    tile.index = {1, -2};
    tile.version = 3;
    tile.cells.assign(kTileCells, LogOdds{-40});
    state.tiles.push_back(std::move(tile));
    std::ofstream(base / "map-3.tiles", std::ios::binary) << EncodeTiles(state);
    std::ofstream(base / "trajectory-3.tum") << "1.0 0.1 0.2 0 0 0 0 1\n";
    return base;
  }();
  return dir;
}

void CheckLoad(const std::string& meta) {
  const auto& dir = StateDir();
  std::ofstream(dir / "state.json", std::ios::binary | std::ios::trunc) << meta;
  const Result<std::optional<SavedState>> outcome = LoadState(dir.string());
  if (!outcome.ok()) {
    Check(!outcome.Message().empty(), "LoadState failed without a reason");
    return;
  }
  if (outcome.value()) {
    Check(outcome.value()->tiles.size() == 1, "LoadState read another tile file");
    Check(outcome.value()->trajectory.size() == 1, "LoadState read another trajectory");
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size == 0) return 0;
  const std::string rest(reinterpret_cast<const char*>(data + 1), size - 1);
  switch (data[0] % 4) {
    case 0: {
      std::string file(kMagic, 8);
      file += rest;
      const uint64_t sum = TileFileChecksum(file);
      file.append(reinterpret_cast<const char*>(&sum), sizeof(sum));
      CheckDecoded(file);
      break;
    }
    case 1:
      CheckDecoded(rest);
      break;
    case 2:
      CheckTum(rest);
      break;
    default:
      CheckLoad(rest);
      break;
  }
  return 0;
}
