#ifndef IRRR_TESTS_FUZZ_DAEMON_RECORDS_H_
#define IRRR_TESTS_FUZZ_DAEMON_RECORDS_H_

// The input of fuzz_daemon_input: several raw messages, each on one of the daemon's input
// channels, so that one input can hold a keyframe sequence and the loops between its keys.
// Shared by the target (SplitRecords) and the seed generator (AppendRecord).
//
// An input is a sequence of records, each
//   1 byte   bits 0-6: the channel, modulo 4 (0 keyframe, 1 loop, 2 session, 3 solution
//            request); bit 7: the queue is applied right after this message (Tick and
//            ProcessQueued, a worker that keeps up), else it waits in the queue with what follows
//            (a worker that lags: the queue limit)
//   4 bytes  the message length n, little endian
//   n bytes  the raw message as it comes off the wire (Service::Receive)
// Every input is valid: a length beyond the end of the input takes what is left, and a record cut
// inside its length field holds the bytes after its channel byte.

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "daemon/common/irrr_config.h"

namespace irrr::fuzz {

struct Record {
  int channel = 0;  // 0 keyframe, 1 loop, 2 session, 3 solution request
  bool apply_after = false;
  const uint8_t* data = nullptr;
  int size = 0;
};

inline constexpr int kNumChannels = 4;

inline const std::string& ChannelName(const DaemonChannels& channels, int channel) {
  switch (channel) {
    case 0:
      return channels.keyframe;
    case 1:
      return channels.loop;
    case 2:
      return channels.session;
  }
  return channels.solution_request;
}

// The inverse of ChannelName: the record channel of an input channel name (-1: none).
inline int ChannelIndex(const DaemonChannels& channels, const std::string& name) {
  for (int channel = 0; channel < kNumChannels; ++channel) {
    if (ChannelName(channels, channel) == name) return channel;
  }
  return -1;
}

inline std::vector<Record> SplitRecords(const uint8_t* data, size_t size) {
  std::vector<Record> records;
  size_t at = 0;
  while (at < size) {
    Record r;
    r.channel = (data[at] & 0x7f) % kNumChannels;
    r.apply_after = (data[at] & 0x80) != 0;
    ++at;
    size_t length = size - at;
    if (size - at >= 4) {
      const uint32_t declared = uint32_t{data[at]} | uint32_t{data[at + 1]} << 8 |
                                uint32_t{data[at + 2]} << 16 | uint32_t{data[at + 3]} << 24;
      at += 4;
      length = std::min<size_t>(declared, size - at);
    }
    r.data = data + at;
    r.size = static_cast<int>(length);
    at += length;
    records.push_back(r);
  }
  return records;
}

// Appends one record; `channel` is 0 to 3.
inline void AppendRecord(int channel,
                         bool apply_after,
                         const std::vector<uint8_t>& message,
                         std::vector<uint8_t>* out) {
  out->push_back(static_cast<uint8_t>(channel | (apply_after ? 0x80 : 0)));
  const auto n = static_cast<uint32_t>(message.size());
  for (int shift = 0; shift < 32; shift += 8) out->push_back(static_cast<uint8_t>(n >> shift));
  out->insert(out->end(), message.begin(), message.end());
}

}  // namespace irrr::fuzz

#endif  // IRRR_TESTS_FUZZ_DAEMON_RECORDS_H_
