#include "daemon/common/thread_pool.h"

#include <algorithm>

namespace irrr {

ThreadPool::ThreadPool(int threads) {
  const int started = std::clamp(threads, 1, kMaxThreads) - 1;
  workers_.reserve(started);
  for (int k = 0; k < started; ++k) workers_.emplace_back([this] { WorkerLoop(); });
}

ThreadPool::~ThreadPool() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stopping_ = true;
  }
  work_ready_.notify_all();
  for (std::thread& worker : workers_) worker.join();
}

int ThreadPool::DefaultThreads() {
  const unsigned cores = std::thread::hardware_concurrency();
  return std::clamp(static_cast<int>(cores), 1, kMaxThreads);
}

void ThreadPool::Drain(std::unique_lock<std::mutex>* lock) {
  while (body_ != nullptr && next_ < total_) {
    const int item = next_++;
    const std::function<void(int)>& body = *body_;
    lock->unlock();
    body(item);
    lock->lock();
    if (++finished_ == total_) work_done_.notify_all();
  }
}

void ThreadPool::WorkerLoop() {
  std::unique_lock<std::mutex> lock(mutex_);
  uint64_t seen = generation_;
  while (true) {
    work_ready_.wait(lock, [&] { return stopping_ || generation_ != seen; });
    if (stopping_) return;
    seen = generation_;
    Drain(&lock);
  }
}

void ThreadPool::Run(int n, const std::function<void(int)>& body) {
  if (n <= 0) return;
  if (workers_.empty() || n == 1) {
    for (int k = 0; k < n; ++k) body(k);
    return;
  }
  std::unique_lock<std::mutex> lock(mutex_);
  body_ = &body;
  total_ = n;
  next_ = 0;
  finished_ = 0;
  ++generation_;
  work_ready_.notify_all();
  Drain(&lock);
  work_done_.wait(lock, [&] { return finished_ == total_; });
  body_ = nullptr;
}

}  // namespace irrr
