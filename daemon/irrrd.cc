// irrrd: the iRRR loop-closing daemon. Hears keyframes, loop hypotheses and session events over
// LCM, decides which loops to trust (iRRR) and publishes corrections, verdicts and a status
// heartbeat (message types in lcmtypes/, behaviour in daemon/service.h).
//
//   irrrd [--config FILE] [--lcm-url URL] [--daemon-id ID] [--log-level LEVEL] [--journal FILE]
//         [--print-config]
//
// With a journal (daemon.journal.path), every input taken is appended to it before it is applied,
// and a start replays it first: after a crash, kill -9 included, the daemon has the state it had,
// and producers resend what it lost meanwhile (IRRR_RESYNC). Snapshots of the state next to it
// (every daemon.journal.snapshot_every inputs, and at a clean stop) spare a restart the steps
// they cover; past daemon.journal.compact_mb the whole state goes to a base and the journal
// starts again after it.
// Threads: the main thread receives (LCM and signals, through poll) and publishes the status; a
// worker applies the inputs and runs the iRRR steps, so that receiving never waits for an
// optimization. SIGTERM and SIGINT: stop receiving, apply what was received, publish a STOPPING
// status, exit 0. SIGHUP: read the configuration again and apply what can change live (log level,
// status rate); the rest is logged as needing a restart. Exit codes follow sysexits.h.

#include <poll.h>
#include <pthread.h>
#include <signal.h>
#include <sys/signalfd.h>
#include <sysexits.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>
#include <CLI/CLI.hpp>
#include <lcm/lcm-cpp.hpp>

#include "daemon/common/allocator.h"
#include "daemon/common/irrr_config.h"
#include "daemon/raw_subscription.h"
#include "daemon/service.h"

namespace irrr {
namespace {

class LcmSink : public MessageSink {
 public:
  explicit LcmSink(lcm::LCM* lcm) : lcm_(lcm) {}
  void Send(const std::string& channel, const std::vector<uint8_t>& bytes) override {
    if (lcm_->publish(channel, bytes.data(), static_cast<unsigned int>(bytes.size())) != 0) {
      spdlog::error("publishing on {} failed", channel);
    }
  }

 private:
  lcm::LCM* lcm_;
};

struct Arguments {
  std::string config;
  std::string lcm_url;
  std::string daemon_id;
  std::string log_level;
  std::string journal;
  bool print_config = false;
};

// Reads the configuration file (if any) and applies the command line. Returns EX_OK or an exit
// code, with the error in `error`.
int LoadConfiguration(const Arguments& args,
                      const CLI::App& app,
                      DaemonOptions* daemon,
                      IrrrOptions* options,
                      std::string* error) {
  DaemonOptions d;
  IrrrOptions o;
  if (!args.config.empty()) {
    if (Status s = LoadDaemonConfig(args.config, &d, &o); !s.ok()) {
      *error = s.message();
      return access(args.config.c_str(), R_OK) != 0 ? EX_NOINPUT : EX_CONFIG;
    }
  }
  if (app.count("--lcm-url") > 0) d.lcm_url = args.lcm_url;
  if (app.count("--daemon-id") > 0) d.daemon_id = args.daemon_id;
  if (app.count("--log-level") > 0) d.log_level = args.log_level;
  if (app.count("--journal") > 0) d.journal.path = args.journal;
  if (Status s = d.Validate(); !s.ok()) {
    *error = "command line: " + s.message();
    return EX_USAGE;
  }
  *daemon = d;
  *options = o;
  return EX_OK;
}

void SetUpLogging(const std::string& level) {
  auto logger = spdlog::stderr_color_mt("irrrd");
  // Under systemd the journal stamps every line itself.
  logger->set_pattern(std::getenv("JOURNAL_STREAM") != nullptr ? "[%l] %v"
                                                               : "%Y-%m-%d %H:%M:%S.%e [%l] %v");
  logger->flush_on(spdlog::level::warn);
  spdlog::set_default_logger(logger);
  spdlog::set_level(spdlog::level::from_str(level));
}

int Run(const Arguments& args, const CLI::App& app) {
  DaemonOptions daemon;
  IrrrOptions options;
  std::string error;
  if (int code = LoadConfiguration(args, app, &daemon, &options, &error); code != EX_OK) {
    std::fprintf(stderr, "irrrd: %s\n", error.c_str());
    return code;
  }
  if (args.print_config) {
    const nlohmann::json config = {{"daemon", DaemonOptionsToJson(daemon)},
                                   {"irrr", IrrrOptionsToJson(options)}};
    std::printf("%s\n", config.dump(2).c_str());
    return EX_OK;
  }
  SetUpLogging(daemon.log_level);

  // Signals are read from a file descriptor; block them before any thread starts.
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGTERM);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGHUP);
  // A shell starts background jobs with SIGINT ignored, and an ignored signal never reaches a
  // signalfd: take the default disposition back before blocking.
  for (int signal_number : {SIGTERM, SIGINT, SIGHUP}) {
    if (sigismember(&signals, signal_number)) std::signal(signal_number, SIG_DFL);
  }
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);
  const int signal_fd = signalfd(-1, &signals, SFD_CLOEXEC);
  if (signal_fd < 0) {
    spdlog::critical("signalfd failed");
    return EX_OSERR;
  }

  lcm::LCM lcm(daemon.lcm_url);
  if (!lcm.good()) {
    spdlog::critical(
        "cannot open LCM at \"{}\" (for udpm://, is there a multicast route? see "
        "docs/daemon.md)",
        daemon.lcm_url.empty() ? "default URL" : daemon.lcm_url);
    return EX_UNAVAILABLE;
  }
  LcmSink sink(&lcm);
  Service service(daemon, options, &sink);
  const DaemonChannels& channels = daemon.channels;
  service.PublishStatus(status_t::STARTING);
  // The journal: replay what it holds (the state before a crash or stop), then append to it.
  Journal journal;
  if (!daemon.journal.path.empty()) {
    JournalRecovery recovery;
    if (Status s = journal.Open(daemon.journal.path, daemon.journal.fsync, &recovery); !s.ok()) {
      spdlog::critical("journal: {}", s.message());
      return EX_IOERR;
    }
    if (!recovery.records.empty() || recovery.dropped_bytes > 0 || recovery.first_record > 0) {
      if (Status s = service.Recover(recovery, daemon.journal.path); !s.ok()) {
        spdlog::critical("journal: {}", s.message());
        return EX_IOERR;
      }
    }
    service.SetJournal(&journal);
  }
  // Set by a session PROGRESS: publish a status now. Only the main thread touches it (handlers
  // run in lcm.handle()).
  bool status_wanted = false;
  auto receive = [&](const lcm::ReceiveBuffer& buffer, const std::string& channel) {
    status_wanted |= service.Receive(
        channel, static_cast<const uint8_t*>(buffer.data), static_cast<int>(buffer.data_size));
  };
  // LCM drops what a subscription has queued beyond its capacity (default 30 messages) while
  // handle() is not called; a burst of keyframes must wait here, not be lost.
  constexpr int kLcmQueueCapacity = 100000;
  std::vector<std::unique_ptr<RawSubscription>> subscriptions;
  for (const std::string& channel :
       {channels.keyframe,
        channels.loop,
        channels.session,
        channels.solution_request,
        channels.correction}) {  // its own, to notice another daemon publishing there
    subscriptions.push_back(
        std::make_unique<RawSubscription>(&lcm, channel, receive, kLcmQueueCapacity));
  }
  spdlog::info(
      "{} listening on {} (inputs {}, {}, {}; corrections on {}, {}, {}; status {} at "
      "{} Hz; errors {}; journal {})",
      daemon.daemon_id,
      daemon.lcm_url.empty() ? "LCM's default URL" : daemon.lcm_url,
      channels.keyframe,
      channels.loop,
      channels.session,
      channels.correction,
      channels.verdicts,
      channels.solution,
      channels.status,
      daemon.status_hz,
      channels.error,
      daemon.journal.path.empty() ? "off" : daemon.journal.path);

  std::atomic<bool> stopping{false};
  std::thread worker([&] {
    while (!stopping.load()) service.ProcessQueued(std::chrono::milliseconds(200));
    while (service.ProcessQueued(std::chrono::milliseconds(0)) > 0) {
    }
  });

  using Clock = std::chrono::steady_clock;
  auto period = std::chrono::duration<double>(1.0 / daemon.status_hz);
  auto next_status = Clock::now();
  auto last_status = Clock::now() - std::chrono::seconds(1);
  constexpr auto kMinStatusGap = std::chrono::milliseconds(20);
  // Re-requests of lost input (Service::Tick) are looked at this often.
  constexpr auto kTickPeriod = std::chrono::milliseconds(20);
  auto next_tick = Clock::now();
  for (;;) {
    const auto now = Clock::now();
    if (now >= next_tick) {
      service.Tick();
      next_tick = now + kTickPeriod;
    }
    if (now >= next_status || (status_wanted && now - last_status >= kMinStatusGap)) {
      service.PublishStatus(status_t::RUNNING);
      status_wanted = false;
      last_status = now;
      next_status = now + std::chrono::duration_cast<Clock::duration>(period);
    }
    const auto until =
        std::min(status_wanted ? last_status + kMinStatusGap : next_status, next_tick);
    const int timeout_ms = static_cast<int>(std::max<int64_t>(
        0,
        std::chrono::duration_cast<std::chrono::milliseconds>(until - Clock::now()).count() + 1));
    pollfd fds[2] = {{lcm.getFileno(), POLLIN, 0}, {signal_fd, POLLIN, 0}};
    if (poll(fds, 2, timeout_ms) < 0) continue;  // EINTR
    if (fds[0].revents & POLLIN) lcm.handle();
    if (!(fds[1].revents & POLLIN)) continue;
    signalfd_siginfo info{};
    if (read(signal_fd, &info, sizeof(info)) != sizeof(info)) continue;
    if (info.ssi_signo == SIGHUP) {
      DaemonOptions new_daemon;
      IrrrOptions new_options;
      if (args.config.empty()) {
        spdlog::info("SIGHUP: no --config file to read again");
      } else if (LoadConfiguration(args, app, &new_daemon, &new_options, &error) != EX_OK) {
        spdlog::error("SIGHUP: configuration not reloaded, keeping the running one: {}", error);
      } else {
        if (new_daemon.log_level != daemon.log_level) {
          spdlog::set_level(spdlog::level::from_str(new_daemon.log_level));
          spdlog::info("SIGHUP: log_level {} -> {}", daemon.log_level, new_daemon.log_level);
          daemon.log_level = new_daemon.log_level;
        }
        if (new_daemon.status_hz != daemon.status_hz) {
          spdlog::info("SIGHUP: status_hz {} -> {}", daemon.status_hz, new_daemon.status_hz);
          daemon.status_hz = new_daemon.status_hz;
          period = std::chrono::duration<double>(1.0 / daemon.status_hz);
          next_status = Clock::now();
        }
        if (DaemonOptionsToJson(new_daemon) != DaemonOptionsToJson(daemon) ||
            IrrrOptionsToJson(new_options) != IrrrOptionsToJson(options)) {
          spdlog::warn(
              "SIGHUP: changes other than log_level and status_hz need a restart; "
              "they are not applied");
        }
      }
      continue;
    }
    spdlog::info("{}: stopping (applying what was received)", strsignal(info.ssi_signo));
    break;
  }

  // Take what is still in the socket, stop receiving, let the worker apply the queue.
  while (lcm.handleTimeout(0) > 0) {
  }
  subscriptions.clear();
  stopping = true;
  service.WakeWorker();
  worker.join();
  if (!daemon.journal.path.empty() && daemon.journal.snapshot_every > 0) {
    if (Status s = service.WriteSnapshot(); !s.ok()) spdlog::error("snapshot: {}", s.message());
  }
  const status_t status = service.CurrentStatus();
  spdlog::info(
      "stopped: {} keyframes, {} loop hypotheses ({} accepted, {} rejected or reversed), {} steps, "
      "{} component(s), {} input(s) rejected",
      status.n_keyframes,
      status.n_hypotheses,
      status.n_accepted,
      status.n_rejected,
      status.n_steps,
      status.n_components,
      status.n_errors);
  service.PublishStatus(status_t::STOPPING);
  spdlog::shutdown();
  close(signal_fd);
  return EX_OK;
}

}  // namespace
}  // namespace irrr

int main(int argc, char** argv) {
  irrr::TuneAllocatorForSolves();
  irrr::Arguments args;
  CLI::App app{"irrrd: the iRRR loop-closing daemon (LCM)"};
  app.add_option("--config", args.config, "JSON configuration (config/irrrd.json documents it)");
  app.add_option("--lcm-url", args.lcm_url, "LCM URL, overriding daemon.lcm_url");
  app.add_option("--daemon-id", args.daemon_id, "sender name, overriding daemon.daemon_id");
  app.add_option("--log-level", args.log_level, "overriding daemon.log_level");
  app.add_option("--journal", args.journal, "journal file, overriding daemon.journal.path");
  app.add_flag("--print-config", args.print_config, "print the effective configuration and exit");
  app.footer(
      "Exit codes: 0 stopped by SIGTERM/SIGINT, 64 usage, 66 configuration missing, 69 LCM "
      "unavailable, 71 system error, 74 journal unreadable, 78 bad configuration.");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);
    return code == 0 ? EX_OK : EX_USAGE;
  }
  return irrr::Run(args, app);
}
