#include "penumbra/sma/cache_snapshot.h"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <bit>
#include <cerrno>
#include <cstring>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "penumbra/common/check.h"
#include "penumbra/common/duration.h"
#include "penumbra/common/hash.h"
#include "penumbra/common/logging.h"

namespace penumbra::sma {

// The format is little-endian and written with memcpy.
static_assert(std::endian::native == std::endian::little, "cache snapshots assume a little-endian host");

namespace {

using Clock = std::chrono::steady_clock;

constexpr char kMagic[8] = {'P', 'N', 'B', 'R', 'S', 'M', 'A', 'C'};
constexpr size_t kHeaderHashOffset = 56;
constexpr uint8_t kShapeSplit4 = 3;

std::string Errno(int error) { return std::strerror(error); }

// Appends fixed-size little-endian values.
class ByteWriter {
 public:
  explicit ByteWriter(std::string& out) : out_(out) {}
  template <class T>
  void Put(T value) {
    static_assert(std::is_trivially_copyable_v<T>);
    char bytes[sizeof(T)];
    std::memcpy(bytes, &value, sizeof(T));
    out_.append(bytes, sizeof(T));
  }
  void Put(const Rgb& c) {
    Put(c.r);
    Put(c.g);
    Put(c.b);
  }

 private:
  std::string& out_;
};

// Reads fixed-size values; the caller has checked the sizes first, so a read
// past the end is a bug (CHECK), never bad input.
class ByteReader {
 public:
  explicit ByteReader(std::span<const char> bytes) : bytes_(bytes) {}
  template <class T>
  T Get() {
    PENUMBRA_CHECK(at_ + sizeof(T) <= bytes_.size(), "cache snapshot read past the end");
    T value;
    std::memcpy(&value, bytes_.data() + at_, sizeof(T));
    at_ += sizeof(T);
    return value;
  }
  Rgb GetRgb() {
    const float r = Get<float>(), g = Get<float>(), b = Get<float>();
    return Rgb(r, g, b);
  }

 private:
  std::span<const char> bytes_;
  size_t at_ = 0;
};

uint64_t Checksum(std::span<const char> bytes) {
  Hasher h;
  h.Update(bytes.data(), bytes.size());
  return h.Digest();
}

Status WriteAll(int fd, std::string_view bytes) {
  size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t n = ::write(fd, bytes.data() + done, bytes.size() - done);
    if (n < 0) {
      if (errno == EINTR) continue;
      return Fail(Errno(errno));
    }
    done += size_t(n);
  }
  return Status::Ok();
}

}  // namespace

// --- Capture, encode, decode -------------------------------------------------

CacheSnapshotData CaptureCacheSnapshot(std::shared_mutex& stateMutex, const Hierarchy& hierarchy,
                                       const SampleCache& cache, size_t chunk) {
  chunk = std::max<size_t>(chunk, 1);
  CacheSnapshotData data;
  {
    std::shared_lock lock(stateMutex);
    data.sceneIdentity = hierarchy.GetScene().identity;
    data.rootCount = uint32_t(hierarchy.RootCount());
    data.baseVertexCount = uint32_t(hierarchy.BaseVertexCount());
    data.nodeCount = uint32_t(hierarchy.NodeCount());
    data.vertexCount = uint32_t(hierarchy.VertexCount());
    data.cacheChanges = cache.Changes();
  }
  // Splits: the children of each split are appended together, so the child
  // groups from RootCount() on are the splits in the order they were made.
  data.splits.reserve((data.nodeCount - data.rootCount) / 2);
  NodeId id = data.rootCount;
  while (id < data.nodeCount) {
    std::shared_lock lock(stateMutex);
    const NodeId stop = NodeId(std::min<size_t>(data.nodeCount, size_t(id) + chunk));
    while (id < stop) {
      const NodeId parentId = hierarchy.GetNode(id).parent;
      const Node& parent = hierarchy.GetNode(parentId);
      PENUMBRA_CHECK(parent.firstChild == id && parent.childCount > 0, "hierarchy children are not grouped by split");
      data.splits.push_back(SplitRecord{parentId, parent.childCount, parent.splitEdge});
      id += parent.childCount;
    }
  }
  data.samples.reserve(data.vertexCount);  // no reallocation while the lock is held
  for (VertexId v = 0; v < data.vertexCount;) {
    std::shared_lock lock(stateMutex);
    const VertexId stop = VertexId(std::min<size_t>(data.vertexCount, size_t(v) + chunk));
    for (; v < stop; ++v) {
      // One consistent copy: samples are improved while the snapshot reads.
      const auto sample = cache.Read(v);
      // Only samples shaded at the scene's initial pose (epoch 0): a restart
      // begins there, so a sample shaded after a move might be wrong for it
      // (moving objects, sma/README.md "Cache on disk").
      if (!sample || sample->epoch != 0) continue;
      data.samples.push_back(ShadedSample{.vertex = v,
                                          .radiance = sample->radiance,
                                          .irradiance = sample->irradiance,
                                          .irradianceStdErr = sample->irradianceStdErr,
                                          .paths = sample->paths,
                                          .round = sample->rounds});
    }
  }
  return data;
}

std::string EncodeCacheSnapshot(const CacheSnapshotData& data) {
  std::string out;
  out.reserve(kCacheSnapshotHeaderBytes + data.splits.size() * kCacheSnapshotSplitBytes +
              data.samples.size() * kCacheSnapshotSampleBytes);
  out.append(kCacheSnapshotHeaderBytes, '\0');
  ByteWriter w(out);
  for (const SplitRecord& s : data.splits) {
    w.Put(uint32_t(s.node));
    w.Put(uint8_t(s.childCount == 4 ? kShapeSplit4 : s.splitEdge));
  }
  for (const ShadedSample& s : data.samples) {
    w.Put(uint32_t(s.vertex));
    w.Put(s.radiance);
    w.Put(s.irradiance);
    w.Put(s.irradianceStdErr);
    w.Put(uint32_t(s.paths));
    w.Put(uint16_t(s.round));
  }
  std::string header;
  header.reserve(kCacheSnapshotHeaderBytes);
  header.append(kMagic, sizeof kMagic);
  ByteWriter h(header);
  h.Put(kCacheSnapshotFormatVersion);
  h.Put(uint32_t(kCacheSnapshotHeaderBytes));
  h.Put(data.sceneIdentity);
  h.Put(data.rootCount);
  h.Put(data.baseVertexCount);
  h.Put(data.nodeCount);
  h.Put(data.vertexCount);
  h.Put(uint32_t(data.splits.size()));
  h.Put(uint32_t(data.samples.size()));
  h.Put(Checksum(std::span<const char>(out).subspan(kCacheSnapshotHeaderBytes)));
  PENUMBRA_CHECK(header.size() == kHeaderHashOffset, "cache snapshot header layout");
  h.Put(Checksum(header));
  std::memcpy(out.data(), header.data(), kCacheSnapshotHeaderBytes);
  return out;
}

Expected<RestoredCache> DecodeCacheSnapshot(std::span<const char> bytes, const Scene& scene,
                                            const RadianceBounds& bounds) {
  if (bytes.size() < kCacheSnapshotHeaderBytes)
    return Fail(fmt::format("{} bytes is too short for a cache snapshot (header {} bytes): truncated or foreign",
                            bytes.size(), kCacheSnapshotHeaderBytes));
  if (std::memcmp(bytes.data(), kMagic, sizeof kMagic) != 0)
    return Fail("not a Penumbra SMA cache snapshot (its first bytes are not \"PNBRSMAC\")");
  ByteReader r(bytes);
  r.Get<uint64_t>();  // magic
  const uint32_t version = r.Get<uint32_t>();
  if (version != kCacheSnapshotFormatVersion)
    return Fail(fmt::format("format version {}; this SMA reads version {}", version, kCacheSnapshotFormatVersion));
  const uint32_t headerBytes = r.Get<uint32_t>();
  const uint64_t identity = r.Get<uint64_t>();
  const uint32_t rootCount = r.Get<uint32_t>();
  const uint32_t baseVertexCount = r.Get<uint32_t>();
  const uint32_t nodeCount = r.Get<uint32_t>();
  const uint32_t vertexCount = r.Get<uint32_t>();
  const uint32_t splitCount = r.Get<uint32_t>();
  const uint32_t sampleCount = r.Get<uint32_t>();
  const uint64_t payloadChecksum = r.Get<uint64_t>();
  const uint64_t headerChecksum = r.Get<uint64_t>();
  if (headerChecksum != Checksum(bytes.first(kHeaderHashOffset)))
    return Fail("the header is corrupt (its checksum does not match)");
  if (headerBytes != kCacheSnapshotHeaderBytes)
    return Fail(fmt::format("header of {} bytes; version {} has {}", headerBytes, version, kCacheSnapshotHeaderBytes));
  if (identity != scene.identity)
    return Fail(fmt::format("it is a snapshot of scene identity {:016x}; this scene's is {:016x}", identity,
                            scene.identity));
  Hierarchy hierarchy(scene);
  if (rootCount != hierarchy.RootCount() || baseVertexCount != hierarchy.BaseVertexCount())
    return Fail(fmt::format("its hierarchy has {} roots and {} base vertices; this scene's has {} and {}", rootCount,
                            baseVertexCount, hierarchy.RootCount(), hierarchy.BaseVertexCount()));
  // Every count is bounded by the bytes that are really there.
  const uint64_t payload = bytes.size() - kCacheSnapshotHeaderBytes;
  const uint64_t declared =
      uint64_t(splitCount) * kCacheSnapshotSplitBytes + uint64_t(sampleCount) * kCacheSnapshotSampleBytes;
  if (payload != declared)
    return Fail(fmt::format("{} bytes of content, but {} splits and {} samples need {}: the file is {}", payload,
                            splitCount, sampleCount, declared, payload < declared ? "truncated" : "too long"));
  if (payloadChecksum != Checksum(bytes.subspan(kCacheSnapshotHeaderBytes)))
    return Fail("the content is corrupt (its checksum does not match)");
  // ... and by what that many splits can make (each at most 4 nodes and 3
  // vertices) within the hierarchy's id range.
  const uint64_t maxNodes = uint64_t(rootCount) + 4 * uint64_t(splitCount);
  const uint64_t maxVertices = uint64_t(baseVertexCount) + 3 * uint64_t(splitCount);
  if (nodeCount < rootCount || nodeCount > maxNodes || nodeCount >= kNoNode || vertexCount < baseVertexCount ||
      vertexCount > maxVertices || vertexCount >= kNoVertex || sampleCount > vertexCount)
    return Fail(fmt::format("{} nodes, {} vertices and {} samples cannot come from {} splits", nodeCount, vertexCount,
                            sampleCount, splitCount));

  hierarchy.Reserve(nodeCount, vertexCount);  // both bounded by the file's size just above
  for (uint32_t i = 0; i < splitCount; ++i) {
    const NodeId node = r.Get<uint32_t>();
    const uint8_t shape = r.Get<uint8_t>();
    if (shape > kShapeSplit4) return Fail(fmt::format("split {}: unknown shape {}", i, shape));
    const Status applied =
        shape == kShapeSplit4 ? hierarchy.ApplySplit(node, 4, 0) : hierarchy.ApplySplit(node, 2, shape);
    if (!applied) return Fail(fmt::format("split {}: {}", i, applied.error().message));
    // A split adds at least 2 nodes, so this also ends a replay that would
    // outgrow what the header declared.
    if (hierarchy.NodeCount() > nodeCount || hierarchy.VertexCount() > vertexCount)
      return Fail(fmt::format("split {} makes more than the {} nodes and {} vertices declared", i, nodeCount,
                              vertexCount));
  }
  if (hierarchy.NodeCount() != nodeCount || hierarchy.VertexCount() != vertexCount)
    return Fail(fmt::format("the splits make {} nodes and {} vertices; the header declares {} and {}",
                            hierarchy.NodeCount(), hierarchy.VertexCount(), nodeCount, vertexCount));
  if (!hierarchy.Conforming()) return Fail("the splits leave T-vertices (Refine never does)");

  std::vector<ShadedSample> samples;
  samples.reserve(sampleCount);
  for (uint32_t i = 0; i < sampleCount; ++i) {
    ShadedSample s;
    s.vertex = r.Get<uint32_t>();
    s.radiance = r.GetRgb();
    s.irradiance = r.GetRgb();
    s.irradianceStdErr = r.Get<float>();
    s.paths = r.Get<uint32_t>();
    s.round = r.Get<uint16_t>();
    if (s.vertex >= vertexCount) return Fail(fmt::format("sample {}: vertex {} does not exist", i, s.vertex));
    if (!samples.empty() && s.vertex <= samples.back().vertex)
      return Fail(fmt::format("sample {}: vertex {} out of order", i, s.vertex));
    if (s.paths == 0) return Fail(fmt::format("sample {}: vertex {} averages 0 paths", i, s.vertex));
    if (auto ok = bounds.Check(s); !ok)
      return Fail(fmt::format("sample {}: vertex {}: {}", i, s.vertex, ok.error().message));
    samples.push_back(s);
  }
  return RestoredCache{std::move(hierarchy), std::move(samples), splitCount};
}

std::vector<VertexId> UnshadedMidpoints(const Hierarchy& hierarchy, const SampleCache& cache) {
  std::vector<VertexId> out;
  for (VertexId v = VertexId(hierarchy.BaseVertexCount()); v < hierarchy.VertexCount(); ++v)
    if (!cache.IsShaded(v)) out.push_back(v);
  return out;
}

// --- Files -------------------------------------------------------------------

Status WriteFileAtomically(const std::filesystem::path& path, std::string_view bytes) {
  const std::filesystem::path temp = path.string() + ".tmp";
  const int fd = ::open(temp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) return Fail(fmt::format("cannot create {}: {}", temp.string(), Errno(errno)));
  Status status = WriteAll(fd, bytes);
  if (!status) status = Fail(fmt::format("cannot write {}: {}", temp.string(), status.error().message));
  if (status && ::fsync(fd) != 0) status = Fail(fmt::format("cannot fsync {}: {}", temp.string(), Errno(errno)));
  if (::close(fd) != 0 && status) status = Fail(fmt::format("cannot close {}: {}", temp.string(), Errno(errno)));
  if (status && ::rename(temp.c_str(), path.c_str()) != 0)
    status = Fail(fmt::format("cannot rename {} to {}: {}", temp.string(), path.string(), Errno(errno)));
  if (!status) {
    ::unlink(temp.c_str());
    return status;
  }
  // The rename is durable once the directory is.
  const std::filesystem::path dir = path.has_parent_path() ? path.parent_path() : std::filesystem::path(".");
  const int dirFd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dirFd < 0) return Fail(fmt::format("cannot open directory {}: {}", dir.string(), Errno(errno)));
  const int synced = ::fsync(dirFd);
  const int error = errno;
  ::close(dirFd);
  if (synced != 0) return Fail(fmt::format("cannot fsync directory {}: {}", dir.string(), Errno(error)));
  return Status::Ok();
}

Expected<std::string> ReadWholeFile(const std::filesystem::path& path, uint64_t maxBytes) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return Fail(fmt::format("cannot open: {}", Errno(errno)));
  struct stat st {};
  if (::fstat(fd, &st) != 0 || !S_ISREG(st.st_mode)) {
    ::close(fd);
    return Fail("not a regular file");
  }
  if (uint64_t(st.st_size) > maxBytes) {
    ::close(fd);
    return Fail(fmt::format("{} bytes is more than the {} allowed", uint64_t(st.st_size), maxBytes));
  }
  std::string bytes(size_t(st.st_size), '\0');
  size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t n = ::read(fd, bytes.data() + done, bytes.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) break;  // shorter than fstat said: it changed under us; decode will say what is missing
    done += size_t(n);
  }
  ::close(fd);
  bytes.resize(done);
  return bytes;
}

// --- CacheSnapshotter --------------------------------------------------------

Expected<std::unique_ptr<CacheSnapshotter>> CacheSnapshotter::Open(const std::filesystem::path& dir,
                                                                   std::chrono::milliseconds interval) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) return Fail(fmt::format("--cache-dir {}: cannot create it: {}", dir.string(), ec.message()));
  const std::filesystem::path lockPath = dir / "sma-cache.lock";
  const int fd = ::open(lockPath.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (fd < 0) return Fail(fmt::format("--cache-dir {}: cannot create {}: {}", dir.string(), lockPath.string(), Errno(errno)));
  if (::flock(fd, LOCK_EX | LOCK_NB) != 0) {
    const int error = errno;
    ::close(fd);
    if (error == EWOULDBLOCK)
      return Fail(fmt::format("--cache-dir {}: another SMA is using it (it holds {})", dir.string(), lockPath.string()));
    return Fail(fmt::format("--cache-dir {}: cannot lock {}: {}", dir.string(), lockPath.string(), Errno(error)));
  }
  return std::unique_ptr<CacheSnapshotter>(new CacheSnapshotter(dir, interval, fd));
}

CacheSnapshotter::CacheSnapshotter(std::filesystem::path dir, std::chrono::milliseconds interval, int lockFd)
    : dir_(std::move(dir)),
      file_(dir_ / kCacheSnapshotFileName),
      interval_(interval),
      lockFd_(lockFd),
      log_(Logger("sma.cache")) {}

CacheSnapshotter::~CacheSnapshotter() {
  {
    std::lock_guard lock(mutex_);
    stopping_ = true;
  }
  wake_.notify_all();
  if (thread_.joinable()) thread_.join();
  ::close(lockFd_);  // releases the flock
}

std::optional<RestoredCache> CacheSnapshotter::Restore(const Scene& scene, const RadianceBounds& bounds) {
  const auto started = Clock::now();
  std::error_code ec;
  if (!std::filesystem::exists(file_, ec)) {
    log_->info("cache: no snapshot in {}: starting with an empty cache", dir_.string());
    return std::nullopt;
  }
  // Far above any real cache (a million samples take 40 MB); the read
  // allocates the file's size and no more, and decoding checks every count.
  auto bytes = ReadWholeFile(file_, uint64_t(1) << 36);
  if (!bytes) {
    log_->warn("cache: snapshot {} ignored: {}; starting with an empty cache", file_.string(), bytes.error().message);
    return std::nullopt;
  }
  auto restored = DecodeCacheSnapshot(*bytes, scene, bounds);
  if (!restored) {
    log_->warn("cache: snapshot {} ignored: {}; starting with an empty cache (the next snapshot replaces it)",
               file_.string(), restored.error().message);
    return std::nullopt;
  }
  const double ms = Milliseconds(Clock::now() - started);
  log_->info("cache: restored {} samples and {} splits ({} nodes, {} vertices) of scene identity {:016x} from {} "
             "({} bytes) in {:.1f} ms",
             restored->samples.size(), restored->splits, restored->hierarchy.NodeCount(),
             restored->hierarchy.VertexCount(), scene.identity, file_.string(), bytes->size(), ms);
  std::lock_guard lock(mutex_);
  stats_.restoredSamples = restored->samples.size();
  stats_.restoredSplits = restored->splits;
  stats_.restoreMs = ms;
  return std::move(*restored);
}

void CacheSnapshotter::Start(std::shared_mutex& stateMutex, const Hierarchy& hierarchy, const SampleCache& cache) {
  PENUMBRA_CHECK(!thread_.joinable() && !stateMutex_, "CacheSnapshotter started twice");
  stateMutex_ = &stateMutex;
  hierarchy_ = &hierarchy;
  cache_ = &cache;
  {
    // What is on disk already (restored, or nothing at all).
    std::shared_lock lock(stateMutex);
    lastSaved_ = {hierarchy.NodeCount(), cache.Changes()};
  }
  thread_ = std::thread([this] { Loop(); });
}

void CacheSnapshotter::Loop() {
  std::unique_lock lock(mutex_);
  while (!stopping_) {
    if (wake_.wait_for(lock, interval_, [this] { return stopping_; })) break;
    lock.unlock();
    SnapshotIfChanged();
    lock.lock();
  }
}

void CacheSnapshotter::Stop() {
  {
    std::lock_guard lock(mutex_);
    stopping_ = true;
  }
  wake_.notify_all();
  if (thread_.joinable()) thread_.join();
  if (stateMutex_) SnapshotIfChanged();
}

bool CacheSnapshotter::SnapshotIfChanged() {
  if (!stateMutex_) return false;
  std::lock_guard one(snapshotMutex_);
  {
    std::shared_lock lock(*stateMutex_);
    if (std::make_pair(hierarchy_->NodeCount(), cache_->Changes()) == lastSaved_) return false;
  }
  const auto started = Clock::now();
  CacheSnapshotData data = CaptureCacheSnapshot(*stateMutex_, *hierarchy_, *cache_);
  const auto captured = Clock::now();
  const std::string bytes = EncodeCacheSnapshot(data);
  const Status written = WriteFileAtomically(file_, bytes);
  const auto done = Clock::now();
  std::lock_guard lock(mutex_);
  if (!written) {
    ++stats_.failed;
    log_->warn("cache: snapshot not written ({}); the previous one stays; retrying in {} s", written.error().message,
               std::chrono::duration_cast<std::chrono::seconds>(interval_).count());
    return false;
  }
  lastSaved_ = {data.nodeCount, data.cacheChanges};
  ++stats_.written;
  stats_.lastBytes = bytes.size();
  stats_.lastSamples = data.samples.size();
  stats_.lastSplits = data.splits.size();
  stats_.lastCaptureMs = Milliseconds(captured - started);
  stats_.lastWriteMs = Milliseconds(done - captured);
  log_->info("cache: snapshot of {} samples and {} splits written to {}: {} bytes; copied in {:.1f} ms, encoded and "
             "written in {:.1f} ms",
             data.samples.size(), data.splits.size(), file_.string(), bytes.size(), stats_.lastCaptureMs,
             stats_.lastWriteMs);
  return true;
}

CacheSnapshotStats CacheSnapshotter::Stats() const {
  std::lock_guard lock(mutex_);
  return stats_;
}

}  // namespace penumbra::sma
