#include "daemon/service.h"

#include <memory>

#include "daemon/service_state.h"

// The service's work is in service_receive.cc, service_apply.cc, service_publish.cc,
// service_status.cc and service_recovery.cc (service_state.h says which does what).

namespace irrr {

Service::State::State(const DaemonOptions& d, const IrrrOptions& o, MessageSink* s)
    : daemon(d),
      options(o),
      sink(s),
      sequencer(SequencerLimits{d.limits.max_held,
                                std::chrono::milliseconds(d.resync.interval_ms),
                                std::chrono::milliseconds(d.resync.give_up_ms)}),
      se2(o),
      se3(o),
      start_utime(NowUtime()) {
  if (d.merge.window_ms > 0) {
    merger = std::make_unique<StampMerger<Input>>(std::chrono::milliseconds(d.merge.window_ms),
                                                  d.merge.senders);
  }
}

Service::Service(const DaemonOptions& daemon, const IrrrOptions& options, MessageSink* sink)
    : state_(std::make_unique<State>(daemon, options, sink)) {}

Service::~Service() = default;

}  // namespace irrr
