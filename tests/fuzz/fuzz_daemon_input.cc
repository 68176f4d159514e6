// libFuzzer target: the daemon's input path through irrr::Service's public API, as irrrd drives
// it: Receive (decode, field checks, each sender's seq order, queue) for every raw message of the
// input, on the channel its record names (daemon_records.h), Tick (re-requests of lost seqs), then
// ProcessQueued (apply to core's Irrr, run the steps whose clusters closed, publish corrections).
// No journal (SetJournal): the state lives in memory only. Valid keyframes and loops in one input
// reach the iRRR steps; anything else must be answered with an error_t, never crash, leak or trip
// a sanitizer. Checked beyond that: nothing is left in the queue once it is processed.
//
// One Service per input, so that no state leaks from one input to the next (a crash reproduces
// from its input alone); constructing one is cheap beside decoding and applying the messages.

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>
#include <vector>

#include <spdlog/spdlog.h>

#include "core/irrr.h"
#include "core/status.h"
#include "daemon/common/irrr_config.h"
#include "daemon/service.h"
#include "irrr/status_t.hpp"
#include "tests/fuzz/daemon_records.h"

namespace irrr {
namespace {

// Everything the service publishes is dropped (it is encoded all the same).
class DiscardingSink : public MessageSink {
 public:
  void Send(const std::string& /*channel*/, const std::vector<uint8_t>& bytes) override {
    IRRR_CHECK(!bytes.empty());
  }
};

// The defaults, with limits small enough for inputs of a few kB to reach them (a keyframe_t is
// about 470 bytes encoded; 1024 is the least max_message_bytes allowed).
DaemonOptions FuzzDaemonOptions() {
  DaemonOptions daemon;
  daemon.log_level = "off";
  daemon.limits.queue_limit = 32;
  daemon.limits.max_message_bytes = 1024;
  daemon.limits.max_sessions = 4;
  daemon.limits.max_keyframes = 16;
  daemon.limits.max_hypotheses = 8;
  daemon.limits.max_parked = 4;
  daemon.limits.max_held = 4;
  IRRR_CHECK(daemon.Validate().ok());
  return daemon;
}

// The defaults, but clusters close after 2 s of stamps (so that stamps close them too, not only
// END and FLUSH) and the optimizer stops earlier (each input stays fast).
IrrrOptions FuzzIrrrOptions() {
  IrrrOptions options;
  options.cluster_gap = 2.0;
  options.optimizer.max_iterations = 20;
  IRRR_CHECK(options.Validate().ok());
  return options;
}

}  // namespace
}  // namespace irrr

// The service logs a warning per rejected input: off, unless IRRR_FUZZ_LOG is set (to read what
// the daemon makes of a reproducer: IRRR_FUZZ_LOG=1 fuzz_daemon_input <file>).
extern "C" int LLVMFuzzerInitialize(int* /*argc*/, char*** /*argv*/) {
  spdlog::set_level(std::getenv("IRRR_FUZZ_LOG") != nullptr ? spdlog::level::debug
                                                            : spdlog::level::off);
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace irrr;
  static const DaemonOptions daemon = FuzzDaemonOptions();
  static const IrrrOptions options = FuzzIrrrOptions();
  DiscardingSink sink;
  Service service(daemon, options, &sink);
  for (const fuzz::Record& record : fuzz::SplitRecords(data, size)) {
    // As irrrd: a PROGRESS asks for a status at once.
    if (service.Receive(
            fuzz::ChannelName(daemon.channels, record.channel), record.data, record.size)) {
      service.PublishStatus(status_t::RUNNING);
    }
    if (record.apply_after) {
      service.Tick();
      service.ProcessQueued(std::chrono::milliseconds(0));
    }
  }
  service.Tick();
  service.ProcessQueued(std::chrono::milliseconds(0));
  IRRR_CHECK(service.QueueDepth() == 0);
  service.PublishStatus(status_t::STOPPING);
  service.Decisions();
  service.Estimates();
  return 0;
}
