#include "daemon/raw_subscription.h"

#include <utility>

namespace irrr {

RawSubscription::RawSubscription(lcm::LCM* lcm,
                                 const std::string& channel,
                                 Handler handler,
                                 int queue_capacity)
    : lcm_(lcm->getUnderlyingLCM()), handler_(std::move(handler)) {
  if (lcm_ == nullptr) return;
  subscription_ = lcm_subscribe(lcm_, channel.c_str(), &RawSubscription::Dispatch, this);
  if (subscription_ != nullptr) {
    lcm_subscription_set_queue_capacity(subscription_, queue_capacity);
  }
}

RawSubscription::~RawSubscription() {
  if (subscription_ != nullptr) lcm_unsubscribe(lcm_, subscription_);
}

void RawSubscription::Dispatch(const lcm_recv_buf_t* buffer, const char* channel, void* self) {
  const lcm::ReceiveBuffer received{buffer->data, buffer->data_size, buffer->recv_utime};
  static_cast<RawSubscription*>(self)->handler_(received, channel);
}

}  // namespace irrr
