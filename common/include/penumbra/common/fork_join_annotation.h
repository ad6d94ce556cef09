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

}  // namespace penumbra
