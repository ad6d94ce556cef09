#pragma once
// The SMA's work threads and the order they take jobs in (issue 13).
//
// Every client's view jobs and refinement steps share a few threads. One
// FIFO served them in arrival order, so a client's new view waited behind
// the refinement steps other clients had queued. Jobs now carry a class and
// the session they are for:
//
//   new view  >  refresh (re-map of the same view)  >  predicted view  >  refinement step
//
// (A predicted view -- issue 15's camera movement prediction -- traces where
// the client's camera is expected next, to ask early for what it will need:
// after every real view's work, before refinement.)
//
// A waiting job of a higher class always runs first; within a class the
// sessions take turns (round-robin), and one session's jobs run in the order
// it posted them. So a new view waits at most for the jobs already running,
// never for another client's queued refinement, and a client that posts many
// steps cannot starve another one's steps.

#include <array>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <mutex>
#include <optional>
#include <thread>
#include <vector>

namespace penumbra::sma {

/// What a job is for, most urgent first.
enum class JobClass : uint8_t {
  kNewView = 0,     // trace and map a view the client has not seen yet (and texture encodings)
  kRefresh = 1,     // re-map the view already traced (new splits shaded, the client caught up)
  kPrediction = 2,  // trace and map a predicted view, ask for what it lacks (nothing is sent)
  kRefinement = 3,  // one refinement step
};
inline constexpr size_t kJobClasses = 4;

/// The order of waiting jobs: by class, then round-robin across sessions,
/// then FIFO per session. No threads, no locks: JobScheduler guards it.
class FairJobQueue {
 public:
  using Job = std::function<void()>;

  void Push(uint64_t session, JobClass jobClass, Job job);
  /// The job to run next, removed; nullopt when none waits.
  std::optional<Job> Pop();
  void Clear();
  size_t Size() const { return size_; }
  /// Jobs of `jobClass` waiting.
  size_t Size(JobClass jobClass) const;

 private:
  struct ClassQueue {
    std::map<uint64_t, std::deque<Job>> bySession;  // only sessions with waiting jobs
    uint64_t lastServed = 0;                        // the session served last: the next one after it goes first
    bool servedAny = false;
  };
  std::array<ClassQueue, kJobClasses> classes_;
  size_t size_ = 0;
};

/// A fixed set of threads running posted jobs in FairJobQueue order. Visibility
/// work and refinement steps run here, never on an I/O thread. Thread-safe.
class JobScheduler {
 public:
  explicit JobScheduler(int threads);
  /// Stop(), then waits for the running jobs to finish.
  ~JobScheduler();
  JobScheduler(const JobScheduler&) = delete;
  JobScheduler& operator=(const JobScheduler&) = delete;

  /// Queues `job` for `session` (0: no session, e.g. a texture encoding).
  /// Dropped after Stop().
  void Post(uint64_t session, JobClass jobClass, std::function<void()> job);
  /// Drops the queued jobs; jobs posted from now on are dropped too, and the
  /// threads end once their running job returns.
  void Stop();
  /// Stop(), then waits for the running jobs to return (not from one of
  /// its own jobs): after it, no job of this scheduler posts anything.
  void Join();

 private:
  void Loop();

  std::mutex mutex_;
  std::condition_variable wake_;
  FairJobQueue queue_;
  bool stopping_ = false;
  std::vector<std::thread> threads_;
};

}  // namespace penumbra::sma
