// The order in which the SMA's work threads take jobs (job_scheduler.h):
// new views first, sessions in turn, one session's jobs in order.

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "penumbra/sma/job_scheduler.h"

namespace penumbra::sma {
namespace {

// Runs every waiting job in the order Pop() gives, recording their labels.
std::vector<std::string> Drain(FairJobQueue& queue, std::vector<std::string>& ran) {
  while (auto job = queue.Pop()) (*job)();
  return ran;
}

TEST(FairJobQueueTest, ANewViewGoesBeforeEveryQueuedRefinementStep) {
  FairJobQueue queue;
  std::vector<std::string> ran;
  auto job = [&ran](std::string label) { return [&ran, label] { ran.push_back(label); }; };
  // Client 1 has queued refinement steps (and a re-map); client 2's view arrives last.
  queue.Push(1, JobClass::kRefinement, job("1:step a"));
  queue.Push(1, JobClass::kRefinement, job("1:step b"));
  queue.Push(1, JobClass::kRefresh, job("1:remap"));
  queue.Push(2, JobClass::kNewView, job("2:view"));
  EXPECT_EQ(queue.Size(), 4u);
  EXPECT_EQ(queue.Size(JobClass::kRefinement), 2u);
  EXPECT_EQ(Drain(queue, ran), (std::vector<std::string>{"2:view", "1:remap", "1:step a", "1:step b"}));
  EXPECT_EQ(queue.Size(), 0u);
  EXPECT_FALSE(queue.Pop());
}

TEST(FairJobQueueTest, APredictedViewGoesAfterViewsAndRemapsAndBeforeRefinement) {
  FairJobQueue queue;
  std::vector<std::string> ran;
  auto job = [&ran](std::string label) { return [&ran, label] { ran.push_back(label); }; };
  queue.Push(1, JobClass::kRefinement, job("1:step"));
  queue.Push(1, JobClass::kPrediction, job("1:predicted"));
  queue.Push(2, JobClass::kPrediction, job("2:predicted"));
  queue.Push(2, JobClass::kRefresh, job("2:remap"));
  queue.Push(3, JobClass::kNewView, job("3:view"));
  EXPECT_EQ(queue.Size(JobClass::kPrediction), 2u);
  EXPECT_EQ(Drain(queue, ran),
            (std::vector<std::string>{"3:view", "2:remap", "1:predicted", "2:predicted", "1:step"}));
}

TEST(FairJobQueueTest, SessionsTakeTurnsWithinAClassAndKeepTheirOwnOrder) {
  FairJobQueue queue;
  std::vector<std::string> ran;
  auto job = [&ran](std::string label) { return [&ran, label] { ran.push_back(label); }; };
  // Client 3 queued many steps before clients 5 and 9 queued one each.
  for (int i = 0; i < 4; ++i) queue.Push(3, JobClass::kRefinement, job("3:" + std::to_string(i)));
  queue.Push(9, JobClass::kRefinement, job("9:0"));
  queue.Push(5, JobClass::kRefinement, job("5:0"));
  queue.Push(5, JobClass::kRefinement, job("5:1"));
  EXPECT_EQ(Drain(queue, ran), (std::vector<std::string>{"3:0", "5:0", "9:0", "3:1", "5:1", "3:2", "3:3"}));
}

TEST(FairJobQueueTest, TheTurnGoesOnFromTheSessionServedLast) {
  FairJobQueue queue;
  std::vector<std::string> ran;
  auto job = [&ran](std::string label) { return [&ran, label] { ran.push_back(label); }; };
  queue.Push(1, JobClass::kRefinement, job("1:0"));
  queue.Push(2, JobClass::kRefinement, job("2:0"));
  (*queue.Pop())();  // 1 served
  // 1 posts again before 2 ran: 2 still goes first.
  queue.Push(1, JobClass::kRefinement, job("1:1"));
  EXPECT_EQ(Drain(queue, ran), (std::vector<std::string>{"1:0", "2:0", "1:1"}));
  queue.Push(7, JobClass::kNewView, job("7:v"));
  queue.Clear();
  EXPECT_EQ(queue.Size(), 0u);
  EXPECT_FALSE(queue.Pop());
}

// The threaded scheduler in the same order: with its one thread held by a
// running job, a view posted after another client's steps runs before them.
TEST(JobSchedulerTest, AViewPostedBehindAnotherClientsStepsRunsFirst) {
  std::mutex mutex;
  std::condition_variable changed;
  bool release = false;
  bool started = false;
  std::vector<std::string> ran;
  {
    JobScheduler scheduler(1);
    scheduler.Post(1, JobClass::kRefinement, [&] {
      std::unique_lock lock(mutex);
      started = true;
      changed.notify_all();
      changed.wait(lock, [&] { return release; });
      ran.push_back("1:running");
    });
    {
      std::unique_lock lock(mutex);
      changed.wait(lock, [&] { return started; });
    }
    auto record = [&](std::string label) {
      return [&, label] {
        std::lock_guard lock(mutex);
        ran.push_back(label);
        changed.notify_all();
      };
    };
    scheduler.Post(1, JobClass::kRefinement, record("1:step"));
    scheduler.Post(1, JobClass::kRefinement, record("1:step"));
    scheduler.Post(2, JobClass::kNewView, record("2:view"));
    {
      std::lock_guard lock(mutex);
      release = true;
    }
    changed.notify_all();
    std::unique_lock lock(mutex);
    changed.wait(lock, [&] { return ran.size() == 4; });
  }
  EXPECT_EQ(ran, (std::vector<std::string>{"1:running", "2:view", "1:step", "1:step"}));
}

TEST(JobSchedulerTest, StopDropsQueuedAndLaterJobs) {
  bool ran = false;
  {
    JobScheduler scheduler(1);
    scheduler.Stop();
    scheduler.Post(1, JobClass::kNewView, [&ran] { ran = true; });
  }
  EXPECT_FALSE(ran);
}

TEST(JobSchedulerTest, JoinWaitsForTheRunningJobAndDropsTheQueued) {
  // What the SMA's shutdown relies on: after Join nothing of the scheduler
  // runs, so nothing posts to a session any more.
  std::atomic<bool> started{false}, finished{false}, queuedRan{false};
  JobScheduler scheduler(1);
  scheduler.Post(1, JobClass::kNewView, [&] {
    started = true;
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    finished = true;
  });
  scheduler.Post(1, JobClass::kNewView, [&] { queuedRan = true; });
  while (!started) std::this_thread::yield();
  scheduler.Join();
  EXPECT_TRUE(finished);
  EXPECT_FALSE(queuedRan);
  scheduler.Post(1, JobClass::kNewView, [&] { queuedRan = true; });
  scheduler.Join();  // again: nothing to wait for
  EXPECT_FALSE(queuedRan);
}

}  // namespace
}  // namespace penumbra::sma
