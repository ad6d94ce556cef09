#include "penumbra/sma/job_scheduler.h"

#include <algorithm>

namespace penumbra::sma {

void FairJobQueue::Push(uint64_t session, JobClass jobClass, Job job) {
  classes_[size_t(jobClass)].bySession[session].push_back(std::move(job));
  ++size_;
}

std::optional<FairJobQueue::Job> FairJobQueue::Pop() {
  for (ClassQueue& q : classes_) {
    if (q.bySession.empty()) continue;
    // The first session after the one served last, wrapping around.
    auto it = q.servedAny ? q.bySession.upper_bound(q.lastServed) : q.bySession.begin();
    if (it == q.bySession.end()) it = q.bySession.begin();
    Job job = std::move(it->second.front());
    it->second.pop_front();
    q.lastServed = it->first;
    q.servedAny = true;
    if (it->second.empty()) q.bySession.erase(it);
    --size_;
    return job;
  }
  return std::nullopt;
}

void FairJobQueue::Clear() {
  for (ClassQueue& q : classes_) q.bySession.clear();
  size_ = 0;
}

size_t FairJobQueue::Size(JobClass jobClass) const {
  size_t n = 0;
  for (const auto& [session, jobs] : classes_[size_t(jobClass)].bySession) n += jobs.size();
  return n;
}

JobScheduler::JobScheduler(int threads) {
  for (int i = 0; i < std::max(1, threads); ++i) threads_.emplace_back([this] { Loop(); });
}

JobScheduler::~JobScheduler() { Join(); }

void JobScheduler::Join() {
  Stop();
  for (auto& t : threads_)
    if (t.joinable()) t.join();
}

void JobScheduler::Post(uint64_t session, JobClass jobClass, std::function<void()> job) {
  {
    std::lock_guard lock(mutex_);
    if (stopping_) return;
    queue_.Push(session, jobClass, std::move(job));
  }
  wake_.notify_one();
}

void JobScheduler::Stop() {
  {
    std::lock_guard lock(mutex_);
    stopping_ = true;
    queue_.Clear();
  }
  wake_.notify_all();
}

void JobScheduler::Loop() {
  while (true) {
    std::function<void()> job;
    {
      std::unique_lock lock(mutex_);
      wake_.wait(lock, [this] { return stopping_ || queue_.Size() > 0; });
      if (stopping_) return;
      job = std::move(*queue_.Pop());
    }
    job();
  }
}

}  // namespace penumbra::sma
