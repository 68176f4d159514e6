#include "clients/bench/child_process.h"

#include <poll.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <string>
#include <type_traits>

namespace irrr {
namespace {

// Moves `size` bytes between `data` and the pipe end `fd` with `io` (read or write), as many
// calls as it takes; false on an error or an early end of the pipe.
template <class Buffer, class Io>
bool Transfer(int fd, Buffer* data, size_t size, Io io) {
  auto* bytes =
      reinterpret_cast<std::conditional_t<std::is_const_v<Buffer>, const char, char>*>(data);
  while (size > 0) {
    const ssize_t n = io(fd, bytes, size);
    if (n <= 0) return false;
    bytes += n;
    size -= static_cast<size_t>(n);
  }
  return true;
}

Status SystemError(const char* call) {
  return Status::Error(std::string(call) + ": " + std::strerror(errno));
}

}  // namespace

Status RunInChildProcess(const std::function<bool(std::vector<double>*)>& work,
                         double limit_seconds,
                         ChildResult* result) {
  int fds[2];
  if (pipe(fds) != 0) return SystemError("pipe");
  std::fflush(stdout);
  std::fflush(stderr);
  const pid_t child = fork();
  if (child < 0) return SystemError("fork");
  if (child == 0) {
    close(fds[0]);
    std::vector<double> numbers;
    const bool ok = work(&numbers);
    if (!ok) numbers.clear();
    const size_t count = numbers.size();
    const bool written = Transfer(fds[1], &count, sizeof(count), write) &&
                         Transfer(fds[1], numbers.data(), count * sizeof(double), write);
    close(fds[1]);
    _exit(ok && written ? 0 : 1);
  }
  close(fds[1]);
  // The child writes only when done: waiting for its first byte is waiting for the work.
  if (limit_seconds > 0.0) {
    pollfd ready{fds[0], POLLIN, 0};
    if (poll(&ready, 1, static_cast<int>(1e3 * limit_seconds)) == 0) {
      kill(child, SIGKILL);
      waitpid(child, nullptr, 0);
      close(fds[0]);
      *result = ChildResult();
      result->stopped = true;
      return Status::Ok();
    }
  }
  size_t count = 0;
  std::vector<double> numbers;
  bool read_ok = Transfer(fds[0], &count, sizeof(count), read);
  if (read_ok) {
    numbers.resize(count);
    read_ok = Transfer(fds[0], numbers.data(), count * sizeof(double), read);
  }
  close(fds[0]);
  int status = 0;
  rusage usage{};
  if (wait4(child, &status, 0, &usage) != child) return SystemError("wait4");
  if (!WIFEXITED(status) || WEXITSTATUS(status) != 0 || !read_ok) {
    return Status::Error("the run failed (see above)");
  }
  result->numbers = std::move(numbers);
  result->peak_rss_kb = usage.ru_maxrss;
  result->stopped = false;
  return Status::Ok();
}

}  // namespace irrr
