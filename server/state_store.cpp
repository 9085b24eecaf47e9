#include "server/state_store.hpp"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <string_view>
#include <system_error>
#include <utility>

#include "engine/io/atomic_file.hpp"
#include "engine/io/map_image.hpp"
#include "engine/io/tum.hpp"

namespace slam::server {
namespace {

namespace fs = std::filesystem;

constexpr char kMagic[8] = {'S', 'L', 'M', 'T', 'I', 'L', 'E', '1'};
constexpr int kFormat = 1;

// Little-endian fixed-width fields (the robot and the workstation may differ in nothing else).
template <typename T>
void Put(std::string& out, T value) {
  static_assert(std::is_trivially_copyable_v<T>);
  char bytes[sizeof(T)];
  std::memcpy(bytes, &value, sizeof(T));
  out.append(bytes, sizeof(T));
}

class Reader {
 public:
  explicit Reader(std::string_view bytes) : bytes_(bytes) {}
  template <typename T>
  bool Get(T& value) {
    if (bytes_.size() - pos_ < sizeof(T)) return false;
    std::memcpy(&value, bytes_.data() + pos_, sizeof(T));
    pos_ += sizeof(T);
    return true;
  }
  size_t remaining() const { return bytes_.size() - pos_; }

 private:
  std::string_view bytes_;
  size_t pos_ = 0;
};

// A tile in the file: its index, its version, its cells.
constexpr size_t kTileBytes = 2 * sizeof(int32_t) + sizeof(uint64_t) + kTileCells * sizeof(LogOdds);

// What the files state.json names can hold at most; anything larger was not written by a save
// (and is refused before it is read: a link to /dev/zero or a huge file would exhaust memory).
// A tile file: header, every tile the map's bound allows (kMapTileBound), checksum.
constexpr uint64_t kMaxTilesFileBytes =
    sizeof(kMagic) + sizeof(uint32_t) + sizeof(double) + 2 * sizeof(uint64_t) +
    uint64_t{2 * kMapTileBound} * uint64_t{2 * kMapTileBound} * kTileBytes + sizeof(uint64_t);
// state.json holds a few names and numbers (about 300 bytes).
constexpr uint64_t kMaxStateJsonBytes = 64 * 1024;
// A saved trajectory line is about 70 bytes: 256 MiB is some 3.8 million scans, four days at 10
// scans a second.
constexpr uint64_t kMaxTrajectoryBytes = uint64_t{256} << 20;

}  // namespace

uint64_t TileFileChecksum(std::string_view bytes) {
  uint64_t h = 1469598103934665603ULL;  // FNV-1a, 64 bits
  for (const char c : bytes) {
    h ^= static_cast<uint8_t>(c);
    h *= 1099511628211ULL;
  }
  return h;
}

std::string EncodeTiles(const SavedState& state) {
  std::string out(kMagic, sizeof(kMagic));
  Put<uint32_t>(out, static_cast<uint32_t>(kTileSize));
  Put<double>(out, state.resolution_m);
  Put<uint64_t>(out, state.version);
  Put<uint64_t>(out, state.tiles.size());
  for (const SavedTile& tile : state.tiles) {
    Put<int32_t>(out, tile.index.x);
    Put<int32_t>(out, tile.index.y);
    Put<uint64_t>(out, tile.version);
    out.append(reinterpret_cast<const char*>(tile.cells.data()),
               tile.cells.size() * sizeof(LogOdds));
  }
  Put<uint64_t>(out, TileFileChecksum(out));
  return out;
}

Result<SavedState> DecodeTiles(const std::string& bytes) {
  SavedState state;
  if (bytes.size() < sizeof(kMagic) + sizeof(uint64_t) ||
      std::memcmp(bytes.data(), kMagic, sizeof(kMagic)) != 0) {
    return Error("not a slamd tile file (bad magic)");
  }
  const size_t body = bytes.size() - sizeof(uint64_t);
  uint64_t stored = 0;
  std::memcpy(&stored, bytes.data() + body, sizeof(stored));
  if (stored != TileFileChecksum(std::string_view(bytes).substr(0, body))) {
    return Error("checksum mismatch (truncated or damaged)");
  }
  // A view, not a copy: a tile file can be hundreds of megabytes.
  Reader in(std::string_view(bytes).substr(sizeof(kMagic), body - sizeof(kMagic)));
  uint32_t tile_size = 0;
  uint64_t count = 0;
  if (!in.Get(tile_size) || !in.Get(state.resolution_m) || !in.Get(state.version) ||
      !in.Get(count)) {
    return Error("truncated header");
  }
  if (tile_size != static_cast<uint32_t>(kTileSize)) {
    return Error("tile size " + std::to_string(tile_size) + ", this build uses " +
                 std::to_string(kTileSize));
  }
  if (!(state.resolution_m > 0.0) || !std::isfinite(state.resolution_m)) {
    return Error("bad resolution");
  }
  // Map versions only grow, by one per scan at most: a version this large is not a saved run's
  // (and would wrap the resumed map's versions).
  constexpr uint64_t kMaxVersion = uint64_t{1} << 62;
  if (state.version >= kMaxVersion) {
    return Error("map version " + std::to_string(state.version) +
                 " is out of range (at most 2^62)");
  }
  if (count != in.remaining() / kTileBytes || in.remaining() % kTileBytes != 0) {
    return Error("tile count does not match the file size");
  }
  state.tiles.clear();
  state.tiles.reserve(count);
  std::set<std::pair<int32_t, int32_t>> seen;
  for (uint64_t i = 0; i < count; ++i) {
    SavedTile tile;
    tile.cells.resize(kTileCells);
    in.Get(tile.index.x);
    in.Get(tile.index.y);
    in.Get(tile.version);
    if (!InMapBound(tile.index)) {
      return Error("tile " + std::to_string(i) + " at (" + std::to_string(tile.index.x) + ", " +
                   std::to_string(tile.index.y) + ") is outside the map's bound (tiles -" +
                   std::to_string(kMapTileBound) + " to " + std::to_string(kMapTileBound - 1) +
                   ")");
    }
    if (!seen.insert({tile.index.x, tile.index.y}).second) {
      return Error("tile " + std::to_string(i) + " at (" + std::to_string(tile.index.x) + ", " +
                   std::to_string(tile.index.y) + ") appears twice");
    }
    for (LogOdds& cell : tile.cells) {
      in.Get(cell);
      // Saves hold clamped cells only; anything beyond the encoding's limit was not written here.
      if (cell < -kLogOddsLimit || cell > kLogOddsLimit) {
        return Error("tile " + std::to_string(i) + " has a cell of " + std::to_string(cell) +
                     ", beyond the log-odds limit of " + std::to_string(kLogOddsLimit));
      }
    }
    state.tiles.push_back(std::move(tile));
  }
  return state;
}

namespace {

bool IsVersionedName(const std::string& name) {
  return (name.rfind("map-", 0) == 0 && name.ends_with(".tiles")) ||
         (name.rfind("trajectory-", 0) == 0 && name.ends_with(".tum"));
}

/// The versioned files the committed state.json in `base` names (none when there is none).
std::set<std::string> CommittedNames(const fs::path& base) {
  std::set<std::string> names;
  const Result<std::string> text =
      io::ReadRegularFile((base / "state.json").string(), kMaxStateJsonBytes);
  if (!text.ok()) return names;
  const nlohmann::json meta = nlohmann::json::parse(text.value(), nullptr, false);
  if (!meta.is_object()) return names;
  for (const char* key : {"tiles_file", "trajectory_file"}) {
    const auto it = meta.find(key);
    if (it != meta.end() && it->is_string()) names.insert(it->get<std::string>());
  }
  return names;
}

/// Removes the versioned files not in `keep`, and temporaries (what a save killed in the middle,
/// or one that failed, left behind; saves are one at a time: none is in flight).
void RemoveUnnamed(const fs::path& base, const std::set<std::string>& keep) {
  std::error_code ec;
  std::vector<fs::path> doomed;
  for (const auto& entry : fs::directory_iterator(base, ec)) {
    const std::string name = entry.path().filename().string();
    const bool temporary = name.find(".tmp-") != std::string::npos;
    if ((IsVersionedName(name) && !keep.contains(name)) || temporary)
      doomed.push_back(entry.path());
  }
  for (const fs::path& path : doomed) fs::remove(path, ec);
}

}  // namespace

Result<SaveReport> SaveState(const std::string& dir, const SaveInputs& in) {
  SaveReport report;
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) {
    return Error(dir + ": cannot create: " + ec.message());
  }

  SavedState state;
  state.version = in.version;
  state.resolution_m = in.resolution_m;
  for (const TileRef& ref : in.grid->Tiles()) {
    SavedTile tile;
    tile.index = ref.index;
    tile.version = in.version_base + ref.tile->version;
    tile.cells.assign(ref.tile->cells.begin(), ref.tile->cells.end());
    state.tiles.push_back(std::move(tile));
  }
  const std::string v = std::to_string(in.version);
  const std::string tiles_name = "map-" + v + ".tiles";
  const std::string trajectory_name = "trajectory-" + v + ".tum";
  const fs::path base(dir);
  const std::string tum = io::FormatTum(in.trajectory);

  // Space first: what no state.json names (left by a failed or killed save) goes before the new
  // files are written, and whatever this save wrote goes again if it cannot commit. A full disk
  // thus fails this save only, never the next one once space is back.
  const std::set<std::string> committed = CommittedNames(base);
  RemoveUnnamed(base, committed);
  const auto fail = [&](std::string error) {
    RemoveUnnamed(base, committed);
    return Result<SaveReport>(Error(std::move(error)));
  };
  if (Result<void> w = io::WriteFileAtomic((base / tiles_name).string(), EncodeTiles(state));
      !w.ok()) {
    return fail(w.Message());
  }
  if (Result<void> w = io::WriteFileAtomic((base / trajectory_name).string(), tum); !w.ok()) {
    return fail(w.Message());
  }

  nlohmann::json meta;
  meta["format"] = kFormat;
  meta["version"] = in.version;
  meta["resolution_m"] = in.resolution_m;
  meta["tiles"] = state.tiles.size();
  meta["tiles_file"] = tiles_name;
  meta["trajectory_file"] = trajectory_name;
  if (!in.trajectory.empty()) {
    const TimedPose& last = in.trajectory.back();
    meta["pose"] = {
        {"t", last.t}, {"x", last.pose.x}, {"y", last.pose.y}, {"theta", last.pose.theta}};
  }
  if (Result<void> w = io::WriteFileAtomic((base / "state.json").string(), meta.dump(2) + "\n");
      !w.ok()) {
    return fail(w.Message());
  }
  // Committed: the superseded versioned files go before the copies are written.
  RemoveUnnamed(base, {tiles_name, trajectory_name});

  // Copies for people and map_server. The state is committed whatever happens to them: a copy
  // that cannot be written is a warning, and the previous copy stays as it was.
  const auto warn = [&](const Result<void>& written) {
    if (!written.ok()) report.warnings.push_back(written.Message());
  };
  const io::GridImage image = io::MakeGridImage(*in.grid);
  warn(io::WritePgm((base / "map.pgm").string(), image));
  warn(io::WriteMapYaml((base / "map.yaml").string(), "map.pgm", image));
  const Result<io::PngBytes> png = io::EncodeGrayPng(image.width, image.height, image.gray);
  if (!png.ok()) {
    warn(Error((base / "map.png").string() + ": " + png.Message()));
  } else {
    warn(io::WriteFileAtomic((base / "map.png").string(),
                             std::string(png.value().begin(), png.value().end())));
  }
  warn(io::WriteFileAtomic((base / "trajectory.tum").string(), tum));
  RemoveUnnamed(base, {tiles_name, trajectory_name});  // temporaries of failed copies
  return report;
}

Result<StateDirLock> StateDirLock::Acquire(const std::string& dir) {
  const auto failed = [&](const std::string& detail) {
    return Result<StateDirLock>(ConfigErrors{{"", "--state-dir " + dir + ": " + detail}});
  };
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) return failed("cannot create: " + ec.message());
  const std::string path = (fs::path(dir) / "slamd.lock").string();
  // The lock file is truncated and written: a link planted there (to any file of the user slamd
  // runs as, or to a path to create) is refused, never followed (O_NOFOLLOW), and so is a FIFO
  // (O_NONBLOCK, then fstat) or a second name of another file (a hard link).
  const int fd =
      ::open(path.c_str(), O_RDWR | O_CREAT | O_NOFOLLOW | O_NONBLOCK | O_NOCTTY | O_CLOEXEC, 0644);
  if (fd < 0) {
    if (errno == ELOOP) return failed(path + " is a symbolic link (not followed); remove it");
    return failed("cannot open " + path + ": " + std::strerror(errno));
  }
  struct stat st {};
  std::string refused;
  if (::fstat(fd, &st) != 0) {
    refused = "cannot stat " + path + ": " + std::strerror(errno);
  } else if (!S_ISREG(st.st_mode)) {
    refused = path + " is not a regular file; remove it";
  } else if (st.st_nlink != 1) {
    refused = path + " has " + std::to_string(st.st_nlink) +
              " names (a hard link to another file); remove it";
  }
  if (!refused.empty()) {
    ::close(fd);
    return failed(refused);
  }
  if (::flock(fd, LOCK_EX | LOCK_NB) != 0) {
    const int why = errno;
    char holder[32] = {};
    const ssize_t n = ::pread(fd, holder, sizeof(holder) - 1, 0);
    ::close(fd);
    if (why != EWOULDBLOCK) return failed("cannot lock " + path + ": " + std::strerror(why));
    std::string pid = n > 0 ? std::string(holder, static_cast<size_t>(n)) : "";
    while (!pid.empty() && (pid.back() == '\n' || pid.back() == ' ')) pid.pop_back();
    return failed("in use by another slamd" + (pid.empty() ? "" : " (pid " + pid + ")") +
                  "; each slamd needs its own state directory");
  }
  // The holder's pid, for the message above (informational: the lock is what counts).
  const std::string pid = std::to_string(::getpid()) + "\n";
  const bool noted = ::ftruncate(fd, 0) == 0 && ::pwrite(fd, pid.data(), pid.size(), 0) > 0;
  (void)noted;  // a lock file without the pid only makes the message above shorter
  return StateDirLock(fd);
}

StateDirLock::StateDirLock(StateDirLock&& other) noexcept : fd_(std::exchange(other.fd_, -1)) {}

StateDirLock& StateDirLock::operator=(StateDirLock&& other) noexcept {
  if (this != &other) {
    if (fd_ >= 0) ::close(fd_);
    fd_ = std::exchange(other.fd_, -1);
  }
  return *this;
}

StateDirLock::~StateDirLock() {
  if (fd_ >= 0) ::close(fd_);
}

Result<std::optional<SavedState>> LoadState(const std::string& dir) {
  const fs::path base(dir);
  const fs::path meta_path = base / "state.json";
  // Nothing saved yet only when nothing at all is there: a link (even a dangling one) or a
  // FIFO in its place is refused by the read below, naming it.
  struct stat st {};
  if (::lstat(meta_path.c_str(), &st) != 0 && errno == ENOENT) {
    return std::optional<SavedState>();
  }
  const Result<std::string> text = io::ReadRegularFile(meta_path.string(), kMaxStateJsonBytes);
  if (!text.ok()) return text.errors();
  const nlohmann::json meta = nlohmann::json::parse(text.value(), nullptr, false);
  if (meta.is_discarded() || !meta.is_object()) {
    return Error(meta_path.string() + ": not valid JSON");
  }
  const auto name_of = [&](const char* key) -> std::optional<std::string> {
    const auto it = meta.find(key);
    if (it == meta.end() || !it->is_string()) return std::nullopt;
    const std::string name = it->get<std::string>();
    // Only plain file names inside the state directory.
    if (name.empty() || name.find('/') != std::string::npos || name == "." || name == "..") {
      return std::nullopt;
    }
    return name;
  };
  const auto format = meta.find("format");
  if (format == meta.end() || !format->is_number_integer() || format->get<int>() != kFormat) {
    return Error(meta_path.string() + ": unknown format (expected \"format\": 1)");
  }
  const auto tiles_name = name_of("tiles_file");
  const auto trajectory_name = name_of("trajectory_file");
  if (!tiles_name || !trajectory_name) {
    return Error(meta_path.string() + ": missing or bad tiles_file / trajectory_file");
  }
  const Result<std::string> bytes =
      io::ReadRegularFile((base / *tiles_name).string(), kMaxTilesFileBytes);
  if (!bytes.ok()) return bytes.errors();
  Result<SavedState> decoded = DecodeTiles(bytes.value());
  if (!decoded.ok()) {
    return Error((base / *tiles_name).string() + ": " + decoded.Message());
  }
  SavedState state = std::move(decoded).value();
  const std::string trajectory_path = (base / *trajectory_name).string();
  const Result<std::string> tum = io::ReadRegularFile(trajectory_path, kMaxTrajectoryBytes);
  if (!tum.ok()) return tum.errors();
  // Poses are where the robot was on this map: a pose beyond the map's bound was not saved by a
  // slamd (and the engine must never be handed one).
  const double half_width_m = double{kMapTileBound} * kTileSize * state.resolution_m;
  auto trajectory =
      io::ParseTum(tum.value(), trajectory_path, {-half_width_m, half_width_m, "the map's bound"});
  if (!trajectory.ok()) {
    return Error(trajectory.Message());
  }
  state.trajectory = std::move(trajectory).value();
  return std::optional<SavedState>(std::move(state));
}

}  // namespace slam::server
