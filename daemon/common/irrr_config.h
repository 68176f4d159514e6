#ifndef IRRR_DAEMON_COMMON_IRRR_CONFIG_H_
#define IRRR_DAEMON_COMMON_IRRR_CONFIG_H_

// The JSON configuration shared by irrr-batch and the daemon (config/irrrd.json). Its "irrr"
// object holds IrrrOptions; the other top-level objects belong to the daemon. Every key of the
// "irrr" object is optional, and the JSON names of all fields are listed once, in irrr_config.cc.
//
//   {
//     "irrr": {
//       "engine": "warm", "alpha": 0.999, "variance_factor": 0, "cluster_gap": 50,
//       "optimizer": {"algorithm": "gauss_newton", "max_iterations": 100, ...}
//     }
//   }

#include <cstdint>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/irrr.h"
#include "core/status.h"

namespace irrr {

// Parses a whole file as JSON, with // and /* */ comments allowed. Fails, naming the path and the
// line and column, on a file that cannot be read or is not JSON; `config` is untouched then.
Status LoadConfigFile(const std::string& path, nlohmann::json* config);

// Reads the "irrr" object into `options`: keys that are present replace the value `options`
// holds, keys that are absent keep it (pass IrrrOptions() for the defaults). Fails on a section
// that is not an object, an unknown key, a value of the wrong type or an unknown enum name, each
// named by its full path from `path` (e.g. `irrr.optimizer.max_iterations: expected an integer,
// got "ten"`), and on options that IrrrOptions::Validate() rejects. `options` is untouched on
// failure.
Status ParseIrrrOptions(const nlohmann::json& irrr_section,
                        IrrrOptions* options,
                        const std::string& path = "irrr");

// The top-level configuration: reads its "irrr" object (if any) as ParseIrrrOptions does and
// ignores every other top-level key. Fails on a configuration that is not an object.
Status ParseIrrrConfig(const nlohmann::json& config, IrrrOptions* options);

// Every field of `options` under its JSON name (the inverse of ParseIrrrOptions).
nlohmann::json IrrrOptionsToJson(const IrrrOptions& options);

// LCM channel names of the daemon (the "daemon.channels" object).
struct DaemonChannels {
  std::string keyframe = "IRRR_KEYFRAME";                  // in: keyframe_t
  std::string loop = "IRRR_LOOP";                          // in: loop_hypothesis_t
  std::string session = "IRRR_SESSION";                    // in: session_event_t
  std::string correction = "IRRR_CORRECTION";              // out: correction_t
  std::string verdicts = "IRRR_VERDICTS";                  // out: verdicts_t
  std::string solution = "IRRR_SOLUTION";                  // out: solution_t
  std::string status = "IRRR_STATUS";                      // out: status_t
  std::string error = "IRRR_ERROR";                        // out: error_t
  std::string resync = "IRRR_RESYNC";                      // out: resync_request_t (to producers)
  std::string solution_request = "IRRR_SOLUTION_REQUEST";  // in: solution_request_t
};

// What the daemon accepts before it answers "limit reached" (the "daemon.limits" object).
struct DaemonLimits {
  int queue_limit = 1000000;          // inputs received but not applied yet
  int max_message_bytes = 1 << 20;    // one encoded input message
  int max_sessions = 1000;            // sessions over the daemon's life
  int64_t max_keyframes = 10000000;   // poses over all sessions
  int64_t max_hypotheses = 10000000;  // loop hypotheses over all sessions
  int max_parked = 100000;            // inputs waiting for a keyframe that has not arrived
  int max_held = 100000;              // inputs waiting for a lost earlier one of their sender
};

// Re-requesting what the network lost (the "daemon.resync" object).
struct DaemonResync {
  int interval_ms = 200;   // an open gap is re-requested this often
  int give_up_ms = 10000;  // ... and skipped after this long without progress
};

// Applying a fleet's inputs in the order of their stamps (the "daemon.merge" object; see
// daemon/stamp_merger.h).
struct DaemonMerge {
  int window_ms = 0;                 // how long an input may wait for a silent sender; 0: off
  std::vector<std::string> senders;  // senders waited for from the start (a fleet's robots)
};

// When journal appends reach the disk (see daemon/journal.h).
enum class JournalSyncPolicy { kNever, kBatch, kAlways };

// The journal of accepted inputs (the "daemon.journal" object).
struct DaemonJournal {
  std::string path;  // "" = no journal (a restart starts empty)
  JournalSyncPolicy fsync = JournalSyncPolicy::kBatch;
  // A snapshot of the state ("<path>.snapshot") every this many inputs, so that a restart runs
  // only the steps of the inputs after it; 0 = none (a restart re-runs every step).
  int snapshot_every = 10000;
  // With snapshots on, also one as soon as the steps since the last one have taken this many
  // seconds: a restart re-runs those steps, so this bounds its time on a large graph whose steps
  // are slow; 0 = by input count only.
  double snapshot_after_s = 2.0;
  // Once the journal holds more than this many megabytes, the worker writes the whole state
  // ("<path>.base") and starts the journal again, empty: the journal stays bounded, and a restart
  // reads the base and replays only the journal after it. 0 = never (the journal keeps every
  // input since the map began).
  double compact_mb = 64.0;
  // With compaction: the journal's old records are kept as "<path>.<first>-<end>" (records
  // numbered from the map's first input) instead of deleted: the inputs' whole history.
  bool keep_compacted = false;
};

// The daemon's own settings (the "daemon" object of config/irrrd.json).
struct DaemonOptions {
  std::string daemon_id = "irrrd";  // sender name of everything it publishes
  std::string lcm_url;              // "" = LCM's default (env LCM_DEFAULT_URL, else udpm ttl=0)
  std::string log_level = "info";   // spdlog: trace, debug, info, warn, error, critical, off
  double status_hz = 1.0;           // heartbeat rate, (0, 100]
  DaemonChannels channels;
  DaemonLimits limits;
  DaemonResync resync;
  DaemonMerge merge;
  DaemonJournal journal;
  // Who may send input: header.sender names (a trailing '*' matches any suffix) and robot ids.
  // Empty = everyone. Messages from others are counted (status_t.n_ignored) and ignored.
  std::vector<std::string> allowed_senders;
  std::vector<int> allowed_robots;

  Status Validate() const;
};

// The daemon's whole configuration: a "daemon" object (DaemonOptions) and an "irrr" object
// (IrrrOptions), both optional, nothing else. Present keys replace the values held, as in
// ParseIrrrOptions; unknown keys (at any level), wrong types and invalid values fail, named by
// their full path. Both outputs are untouched on failure.
Status ParseDaemonConfig(const nlohmann::json& config, DaemonOptions* daemon, IrrrOptions* options);

// LoadConfigFile, then ParseDaemonConfig; errors start with the path.
Status LoadDaemonConfig(const std::string& path, DaemonOptions* daemon, IrrrOptions* options);

// For the daemon's clients (irrr-inject, irrr-listen, irrr-view): the daemon's configuration at
// `path` (empty: the defaults) into `daemon`, for its channel names; and its LCM URL into
// `*lcm_url` unless that is set already (a --lcm-url), so that the clients join the daemon's
// network. Errors start with the path.
Status LoadClientConfig(const std::string& path, DaemonOptions* daemon, std::string* lcm_url);

// Every field of `options` under its JSON name (the inverse of ParseDaemonConfig's "daemon").
nlohmann::json DaemonOptionsToJson(const DaemonOptions& options);

}  // namespace irrr

#endif  // IRRR_DAEMON_COMMON_IRRR_CONFIG_H_
