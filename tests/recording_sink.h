#ifndef IRRR_TESTS_RECORDING_SINK_H_
#define IRRR_TESTS_RECORDING_SINK_H_

// A MessageSink for the service tests: keeps every message the service publishes, by channel.

#include <map>
#include <mutex>
#include <string>
#include <vector>

#include <catch2/catch.hpp>

#include "daemon/service.h"

namespace irrr {

class RecordingSink : public MessageSink {
 public:
  void Send(const std::string& channel, const std::vector<uint8_t>& bytes) override {
    std::lock_guard<std::mutex> lock(mutex_);
    messages_[channel].push_back(bytes);
  }
  // Every message published on `channel`, decoded.
  template <class Message>
  std::vector<Message> Decoded(const std::string& channel) {
    std::lock_guard<std::mutex> lock(mutex_);
    return DecodeFrom<Message>(channel, 0);
  }
  // The messages on `channel` that New has not returned before.
  template <class Message>
  std::vector<Message> New(const std::string& channel) {
    std::lock_guard<std::mutex> lock(mutex_);
    size_t& read = read_[channel];
    std::vector<Message> out = DecodeFrom<Message>(channel, read);
    read += out.size();
    return out;
  }

 private:
  template <class Message>
  std::vector<Message> DecodeFrom(const std::string& channel, size_t first) {
    std::vector<Message> out;
    const std::vector<std::vector<uint8_t>>& all = messages_[channel];
    for (size_t k = first; k < all.size(); ++k) {
      Message m;
      REQUIRE(m.decode(all[k].data(), 0, static_cast<int>(all[k].size())) ==
              static_cast<int>(all[k].size()));
      out.push_back(m);
    }
    return out;
  }

  std::mutex mutex_;
  std::map<std::string, std::vector<std::vector<uint8_t>>> messages_;
  std::map<std::string, size_t> read_;
};

}  // namespace irrr

#endif  // IRRR_TESTS_RECORDING_SINK_H_
