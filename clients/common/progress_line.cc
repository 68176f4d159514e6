#include "clients/common/progress_line.h"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <utility>

namespace irrr {

ProgressLine::ProgressLine(std::FILE* stream) : ProgressLine(stream, isatty(fileno(stream)) != 0) {}

ProgressLine::ProgressLine(std::FILE* stream, bool enabled) : stream_(stream), enabled_(enabled) {}

ProgressLine::~ProgressLine() { Clear(); }

bool ProgressLine::Due() const {
  return enabled_ && std::chrono::steady_clock::now() - last_ >= kRedrawPeriod;
}

void ProgressLine::Update(const std::string& text, bool force) {
  if (!enabled_ || (!force && !Due())) return;
  // "\033[K" erases what a longer previous text left to the right.
  fmt::print(stream_, "\r{}\033[K", text);
  std::fflush(stream_);
  drawn_ = true;
  last_ = std::chrono::steady_clock::now();
}

void ProgressLine::Finish(const std::string& text) {
  if (!enabled_) return;
  fmt::print(stream_, "\r{}\033[K\n", text);
  std::fflush(stream_);
  drawn_ = false;
  last_ = std::chrono::steady_clock::now();
}

void ProgressLine::Clear() {
  if (!enabled_ || !drawn_) return;
  fmt::print(stream_, "\r\033[K");
  std::fflush(stream_);
  drawn_ = false;
}

ElapsedTicker::ElapsedTicker(std::string label, ProgressLine* line)
    : label_(std::move(label)), line_(line) {
  if (!line_->enabled()) return;
  thread_ = std::thread([this] {
    const auto start = std::chrono::steady_clock::now();
    std::unique_lock<std::mutex> lock(mutex_);
    do {
      const double seconds =
          std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      line_->Update(label_ + ", " + FormatElapsed(seconds), /*force=*/true);
    } while (!stop_changed_.wait_for(lock, std::chrono::seconds(1), [this] { return stop_; }));
    line_->Clear();
  });
}

ElapsedTicker::~ElapsedTicker() {
  if (!thread_.joinable()) return;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_ = true;
  }
  stop_changed_.notify_all();
  thread_.join();
}

std::string ProgressBar(size_t done, size_t total, int width) {
  const size_t filled =
      total == 0 ? static_cast<size_t>(width) : std::min(done, total) * width / total;
  return "[" + std::string(filled, '#') + std::string(width - filled, '.') + "]";
}

std::string FormatElapsed(double seconds) {
  if (seconds < 60.0) return fmt::format("{:.1f} s", seconds);
  const auto whole = static_cast<long>(std::floor(seconds));
  return fmt::format("{} min {:02d} s", whole / 60, whole % 60);
}

}  // namespace irrr
