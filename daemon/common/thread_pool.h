#ifndef IRRR_DAEMON_COMMON_THREAD_POOL_H_
#define IRRR_DAEMON_COMMON_THREAD_POOL_H_

// A fixed pool of threads for core's ParallelFor (core runs no threads of its own). The calling
// thread works too, so a pool of N threads starts N - 1; a pool of 1 runs everything inline.
// One ParallelFor at a time (iRRR's calls are not nested); bodies must not throw.

#include <condition_variable>
#include <cstdint>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

#include "core/irrr.h"

namespace irrr {

class ThreadPool {
 public:
  explicit ThreadPool(int threads);
  ~ThreadPool();
  ThreadPool(const ThreadPool&) = delete;
  ThreadPool& operator=(const ThreadPool&) = delete;

  int size() const { return static_cast<int>(workers_.size()) + 1; }

  // Runs body(0), ..., body(n - 1) on the pool and the calling thread; returns when all are done.
  void Run(int n, const std::function<void(int)>& body);

  // Run as core's ParallelFor (the pool must outlive its users).
  ParallelFor AsParallelFor() {
    return [this](int n, const std::function<void(int)>& body) { Run(n, body); };
  }

  // The thread count a "threads" setting of 0 means: the machine's cores, at most kMaxThreads.
  static int DefaultThreads();
  static constexpr int kMaxThreads = 64;

 private:
  void WorkerLoop();
  // Takes and runs items of the current job until none is left.
  void Drain(std::unique_lock<std::mutex>* lock);

  std::vector<std::thread> workers_;
  std::mutex mutex_;
  std::condition_variable work_ready_;
  std::condition_variable work_done_;
  const std::function<void(int)>* body_ = nullptr;
  int total_ = 0;
  int next_ = 0;      // next item to hand out
  int finished_ = 0;  // items done
  uint64_t generation_ = 0;
  bool stopping_ = false;
};

}  // namespace irrr

#endif  // IRRR_DAEMON_COMMON_THREAD_POOL_H_
