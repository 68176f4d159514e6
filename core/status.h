#ifndef IRRR_CORE_STATUS_H_
#define IRRR_CORE_STATUS_H_

#include <cstdio>
#include <cstdlib>
#include <string>
#include <utility>

namespace irrr {

// The outcome of an operation on external input: ok, or an error with a sentence that names the
// offending item, e.g. "line 17: EDGE_SE2 4 4: self-loop".
class Status {
 public:
  static Status Ok() { return Status(); }
  static Status Error(std::string message) { return Status(std::move(message)); }

  bool ok() const { return !error_; }
  const std::string& message() const { return message_; }

 private:
  Status() = default;
  explicit Status(std::string message) : error_(true), message_(std::move(message)) {}

  bool error_ = false;
  std::string message_;
};

}  // namespace irrr

// Broken internal invariants abort in every build type (never used on external input).
#define IRRR_CHECK(condition)                                                            \
  do {                                                                                   \
    if (!(condition)) {                                                                  \
      std::fprintf(stderr, "%s:%d: check failed: %s\n", __FILE__, __LINE__, #condition); \
      std::abort();                                                                      \
    }                                                                                    \
  } while (false)

#endif  // IRRR_CORE_STATUS_H_
