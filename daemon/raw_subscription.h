#ifndef IRRR_DAEMON_RAW_SUBSCRIPTION_H_
#define IRRR_DAEMON_RAW_SUBSCRIPTION_H_

// An LCM subscription that hands over the raw bytes (we decode and check them ourselves), made
// through LCM's C API. The C++ wrapper of Debian's LCM 1.3.1 (lcm::LCM::subscribe with a member
// function) fails UndefinedBehaviorSanitizer's vptr check on every message it dispatches, even in
// a ten-line program, so the daemon, the clients and the tests avoid it.

#include <functional>
#include <string>

#include <lcm/lcm-cpp.hpp>

namespace irrr {

class RawSubscription {
 public:
  using Handler = std::function<void(const lcm::ReceiveBuffer& buffer, const std::string& channel)>;

  // Subscribes `handler` to `channel` (an LCM regular expression) on `lcm`, which must outlive
  // the subscription. LCM drops what a subscription has queued beyond `queue_capacity` messages
  // while handle() is not called (LCM's default: 30).
  RawSubscription(lcm::LCM* lcm, const std::string& channel, Handler handler, int queue_capacity);
  ~RawSubscription();
  RawSubscription(const RawSubscription&) = delete;
  RawSubscription& operator=(const RawSubscription&) = delete;

  bool ok() const { return subscription_ != nullptr; }

 private:
  static void Dispatch(const lcm_recv_buf_t* buffer, const char* channel, void* self);

  lcm_t* lcm_;
  Handler handler_;
  lcm_subscription_t* subscription_ = nullptr;
};

}  // namespace irrr

#endif  // IRRR_DAEMON_RAW_SUBSCRIPTION_H_
