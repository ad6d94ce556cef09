#pragma once
// Makes tbb::parallel_for's hand-offs visible to ThreadSanitizer.
//
// TBB starts its tasks and waits for them in libtbb, which a TSan build does
// not instrument, so TSan sees no order between what the calling thread wrote
// before the loop and what the tasks read, nor between what the tasks wrote
// and what anyone does after the loop -- and reports races that are not
// there (seen: a task reading the sample cache under the caller's shared
// lock, and the network thread writing it after the lock passed on). This
// tells TSan what TBB guarantees:
//
//   ForkJoinAnnotation order;
//   order.Fork();                                 // before parallel_for
//   tbb::parallel_for(range, [&](auto r) {
//     order.Enter();                              // first in every task
//     ...
//     order.Leave();                              // last in every task
//   });
//   order.Join();                                 // after parallel_for
//
// Everything compiles to nothing outside TSan builds.

#if defined(__SANITIZE_THREAD__)
#include <sanitizer/tsan_interface.h>
#include <tbb/global_control.h>
#define PENUMBRA_TSAN_ANNOTATIONS 1
#endif

namespace penumbra {

class ForkJoinAnnotation {
 public:
#if defined(PENUMBRA_TSAN_ANNOTATIONS)
  void Fork() { __tsan_release(&fork_); }
  void Enter() { __tsan_acquire(&fork_); }
  void Leave() { __tsan_release(&join_); }
  void Join() { __tsan_acquire(&join_); }

 private:
  char fork_ = 0;
  char join_ = 0;
#else
  void Fork() {}
  void Enter() {}
  void Leave() {}
  void Join() {}
#endif
};

/// The annotations above cannot reach TBB's own last words: after a loop's
/// body, the worker's inlined (so instrumented) TBB code writes the loop's
/// wait context and `task_group_context` on the caller's stack, and the
/// caller's wait for it is in libtbb. So the caller's next loop, building
/// its own context in the same stack slot, is reported as a race with the
/// worker -- with the SMA's view threads looping back to back, a report
/// every few runs of SmaNonReadingClientTest (three forms: in TBB's
/// `_task.h`, `parallel_for.h`, `_intrusive_list_node.h`, and once with our
/// own `MapHits` frame on top). Debian's TBB is not built with TSan, which
/// would fix it. Instead a process that holds one of these, in a TSan build,
/// runs every TBB loop on its calling thread alone: races between its own
/// threads (I/O, view jobs, renderer links) stay checked; what is lost is
/// TSan's check of a loop body against itself on two TBB workers (those
/// bodies write disjoint slots; AddressSanitizer and the unit tests still
/// run them on every core). Outside TSan builds it is nothing.
class TbbSingleThreadedUnderTsan {
#if defined(PENUMBRA_TSAN_ANNOTATIONS)
  tbb::global_control limit_{tbb::global_control::max_allowed_parallelism, 1};
#endif
};

}  // namespace penumbra
