#pragma once

#include "native/csrc/common.h"

namespace {

// ---- per-thread buffers --------------------------------------------------------------------------

// The calling thread's T, its address taken once per call: in a shared library every use of a
// `thread_local` variable may call __tls_get_addr, and GCC repeats those calls inside loops.
// Each T is one instance per thread, so each use needs a type of its own.
template <typename T>
__attribute__((noinline)) T& ThreadLocal() {
  thread_local T value;
  return value;
}

// ---- work split over XLA's CPU thread pool -------------------------------------------------------

// Runs body(block) for every block. The calling thread works too; a pool task that starts after
// every block is claimed returns without touching `body`, so the call never waits for a task
// the pool has not started (no deadlock when the pool is busy).
template <typename Body>
void ParallelFor(ffi::ThreadPool& pool, int64_t blocks, const Body& body) {
  if (blocks <= 0) return;
  struct State {
    std::atomic<int64_t> next{0};
    std::atomic<int64_t> done{0};
    int64_t blocks = 0;
    std::mutex mutex;
    std::condition_variable finished;
  };
  auto state = std::make_shared<State>();
  state->blocks = blocks;
  const Body* shared_body = &body;
  auto run = [state, shared_body]() {
    for (;;) {
      int64_t b = state->next.fetch_add(1);
      if (b >= state->blocks) return;
      (*shared_body)(b);
      if (state->done.fetch_add(1) + 1 == state->blocks) {
        std::lock_guard<std::mutex> lock(state->mutex);
        state->finished.notify_all();
      }
    }
  };
  int64_t helpers = std::min<int64_t>(pool.num_threads(), blocks - 1);
  for (int64_t i = 0; i < helpers; ++i) pool.Schedule([run]() { run(); });
  run();
  std::unique_lock<std::mutex> lock(state->mutex);
  state->finished.wait(lock, [&] { return state->done.load() == state->blocks; });
}

}  // namespace
