#include "daemon/common/irrr_config.h"

#include <cmath>
#include <fstream>
#include <limits>
#include <set>
#include <sstream>
#include <type_traits>
#include <utility>
#include <vector>

namespace irrr {
namespace {

using nlohmann::json;

// The JSON names of the options, in one place: a new field of IrrrOptions or OptimizerOptions is
// one line here (and one in docs/daemon.md's key tables). Reading, writing and the list of known
// keys all go through these two functions.
template <class Visitor>
void VisitFields(OptimizerOptions& options, Visitor& visit) {
  visit("algorithm", options.algorithm);
  visit("max_iterations", options.max_iterations);
  visit("function_tolerance", options.function_tolerance);
  visit("parameter_tolerance", options.parameter_tolerance);
  visit("initial_damping", options.initial_damping);
}

template <class Visitor>
void VisitFields(IrrrOptions& options, Visitor& visit) {
  visit("engine", options.engine);
  visit("alpha", options.alpha);
  visit("variance_factor", options.variance_factor);
  visit("cluster_gap", options.cluster_gap);
  visit("cluster_span", options.cluster_span);
  visit("arbiter", options.arbiter);
  visit("step_budget", options.step_budget);
  visit("graph_dof", options.graph_dof);
  visit("optimizer", options.optimizer);
}

template <class Visitor>
void VisitFields(DaemonChannels& channels, Visitor& visit) {
  visit("keyframe", channels.keyframe);
  visit("loop", channels.loop);
  visit("session", channels.session);
  visit("correction", channels.correction);
  visit("verdicts", channels.verdicts);
  visit("solution", channels.solution);
  visit("status", channels.status);
  visit("error", channels.error);
  visit("resync", channels.resync);
  visit("solution_request", channels.solution_request);
}

template <class Visitor>
void VisitFields(DaemonLimits& limits, Visitor& visit) {
  visit("queue_limit", limits.queue_limit);
  visit("max_message_bytes", limits.max_message_bytes);
  visit("max_sessions", limits.max_sessions);
  visit("max_keyframes", limits.max_keyframes);
  visit("max_hypotheses", limits.max_hypotheses);
  visit("max_parked", limits.max_parked);
  visit("max_held", limits.max_held);
}

template <class Visitor>
void VisitFields(DaemonMerge& merge, Visitor& visit) {
  visit("window_ms", merge.window_ms);
  visit("senders", merge.senders);
}

template <class Visitor>
void VisitFields(DaemonResync& resync, Visitor& visit) {
  visit("interval_ms", resync.interval_ms);
  visit("give_up_ms", resync.give_up_ms);
}

template <class Visitor>
void VisitFields(DaemonJournal& journal, Visitor& visit) {
  visit("path", journal.path);
  visit("fsync", journal.fsync);
  visit("snapshot_every", journal.snapshot_every);
  visit("snapshot_after_s", journal.snapshot_after_s);
  visit("compact_mb", journal.compact_mb);
  visit("keep_compacted", journal.keep_compacted);
}

template <class Visitor>
void VisitFields(DaemonOptions& options, Visitor& visit) {
  visit("daemon_id", options.daemon_id);
  visit("lcm_url", options.lcm_url);
  visit("log_level", options.log_level);
  visit("status_hz", options.status_hz);
  visit("channels", options.channels);
  visit("limits", options.limits);
  visit("resync", options.resync);
  visit("merge", options.merge);
  visit("journal", options.journal);
  visit("allowed_senders", options.allowed_senders);
  visit("allowed_robots", options.allowed_robots);
}

template <class Enum>
using EnumNames = std::vector<std::pair<Enum, const char*>>;

const EnumNames<IrrrEngine>& NamesOf(IrrrEngine) {
  static const EnumNames<IrrrEngine> names = {
      {IrrrEngine::kWarm, "warm"},
      {IrrrEngine::kPaper, "paper"},
  };
  return names;
}

const EnumNames<GraphDegreesOfFreedom>& NamesOf(GraphDegreesOfFreedom) {
  static const EnumNames<GraphDegreesOfFreedom> names = {
      {GraphDegreesOfFreedom::kResidualRows, "residual_rows"},
      {GraphDegreesOfFreedom::kExact, "exact"},
  };
  return names;
}

const EnumNames<JournalSyncPolicy>& NamesOf(JournalSyncPolicy) {
  static const EnumNames<JournalSyncPolicy> names = {
      {JournalSyncPolicy::kNever, "never"},
      {JournalSyncPolicy::kBatch, "batch"},
      {JournalSyncPolicy::kAlways, "always"},
  };
  return names;
}

const EnumNames<OptimizerAlgorithm>& NamesOf(OptimizerAlgorithm) {
  static const EnumNames<OptimizerAlgorithm> names = {
      {OptimizerAlgorithm::kGaussNewton, "gauss_newton"},
      {OptimizerAlgorithm::kLevenbergMarquardt, "levenberg_marquardt"},
  };
  return names;
}

// A value as the user wrote it, shortened so that a message stays one line.
std::string Quote(const json& value) {
  constexpr size_t kMaxChars = 40;
  std::string text = value.dump();
  if (text.size() > kMaxChars) text = text.substr(0, kMaxChars - 3) + "...";
  return text;
}

// `"a" or "b"`, `"a", "b" or "c"`.
template <class Enum>
std::string Alternatives(const EnumNames<Enum>& names) {
  std::string text;
  for (size_t k = 0; k < names.size(); ++k) {
    if (k > 0) text += k + 1 == names.size() ? " or " : ", ";
    text += std::string("\"") + names[k].second + "\"";
  }
  return text;
}

struct KeyCollector {
  std::set<std::string> keys;
  template <class T>
  void operator()(const char* key, T&) {
    keys.insert(key);
  }
};

// Reads the keys present in one JSON object into an options struct; keeps the first error.
class Reader {
 public:
  Reader(const json& object, std::string path) : object_(object), path_(std::move(path)) {}

  template <class Options>
  Status Read(Options* options) {
    if (!object_.is_object()) return Error(path_, "expected an object, got " + Quote(object_));
    KeyCollector known;
    VisitFields(*options, known);
    for (const auto& item : object_.items()) {
      if (known.keys.count(item.key()) == 0) {
        std::string list;
        for (const std::string& key : known.keys) list += (list.empty() ? "" : ", ") + key;
        return Error(path_ + "." + item.key(), "unknown key (known: " + list + ")");
      }
    }
    VisitFields(*options, *this);
    return status_;
  }

  void operator()(const char* key, double& value) {
    const json* v = Find(key);
    if (v == nullptr) return;
    if (!v->is_number()) return Fail(key, "expected a number, got " + Quote(*v));
    value = v->get<double>();
  }

  void operator()(const char* key, int& value) {
    const json* v = Find(key);
    if (v == nullptr) return;
    if (!v->is_number_integer()) return Fail(key, "expected an integer, got " + Quote(*v));
    const bool fits = v->is_number_unsigned()
                          ? v->get<uint64_t>() <= uint64_t{std::numeric_limits<int>::max()}
                          : v->get<int64_t>() >= std::numeric_limits<int>::min() &&
                                v->get<int64_t>() <= std::numeric_limits<int>::max();
    if (!fits) return Fail(key, "integer out of range: " + Quote(*v));
    value = v->get<int>();
  }

  void operator()(const char* key, int64_t& value) {
    const json* v = Find(key);
    if (v == nullptr) return;
    if (!v->is_number_integer() ||
        (v->is_number_unsigned() &&
         v->get<uint64_t>() > uint64_t{std::numeric_limits<int64_t>::max()})) {
      return Fail(key, "expected an integer, got " + Quote(*v));
    }
    value = v->get<int64_t>();
  }

  void operator()(const char* key, std::string& value) {
    const json* v = Find(key);
    if (v == nullptr) return;
    if (!v->is_string()) return Fail(key, "expected a string, got " + Quote(*v));
    value = v->get<std::string>();
  }

  void operator()(const char* key, std::vector<std::string>& value) {
    const json* v = Find(key);
    if (v == nullptr) return;
    std::vector<std::string> parsed;
    if (!v->is_array()) return Fail(key, "expected an array of strings, got " + Quote(*v));
    for (const json& item : *v) {
      if (!item.is_string()) return Fail(key, "expected an array of strings, got " + Quote(*v));
      parsed.push_back(item.get<std::string>());
    }
    value = std::move(parsed);
  }

  void operator()(const char* key, std::vector<int>& value) {
    const json* v = Find(key);
    if (v == nullptr) return;
    std::vector<int> parsed;
    if (!v->is_array()) return Fail(key, "expected an array of integers, got " + Quote(*v));
    for (const json& item : *v) {
      if (!item.is_number_integer() || item.get<int64_t>() < std::numeric_limits<int>::min() ||
          item.get<int64_t>() > std::numeric_limits<int>::max()) {
        return Fail(key, "expected an array of integers, got " + Quote(*v));
      }
      parsed.push_back(item.get<int>());
    }
    value = std::move(parsed);
  }

  void operator()(const char* key, bool& value) {
    const json* v = Find(key);
    if (v == nullptr) return;
    if (!v->is_boolean()) return Fail(key, "expected true or false, got " + Quote(*v));
    value = v->get<bool>();
  }

  template <class T>
  void operator()(const char* key, T& value) {
    const json* v = Find(key);
    if (v == nullptr) return;
    if constexpr (std::is_enum_v<T>) {
      const auto& names = NamesOf(T());
      if (v->is_string()) {
        for (const auto& [candidate, name] : names) {
          if (v->get<std::string>() == name) {
            value = candidate;
            return;
          }
        }
      }
      Fail(key, "expected " + Alternatives(names) + ", got " + Quote(*v));
    } else {
      Reader nested(*v, path_ + "." + key);
      if (Status s = nested.Read(&value); !s.ok()) status_ = s;
    }
  }

 private:
  static Status Error(const std::string& path, const std::string& message) {
    return Status::Error(path + ": " + message);
  }

  // The value under `key`, or null when it is absent or an earlier key already failed.
  const json* Find(const char* key) const {
    if (!status_.ok()) return nullptr;
    const auto it = object_.find(key);
    return it == object_.end() ? nullptr : &*it;
  }

  void Fail(const char* key, const std::string& message) {
    status_ = Error(path_ + "." + key, message);
  }

  const json& object_;
  std::string path_;
  Status status_ = Status::Ok();
};

class Writer {
 public:
  explicit Writer(json* object) : object_(object) {}

  template <class T>
  void operator()(const char* key, T& value) {
    if constexpr (std::is_enum_v<T>) {
      for (const auto& [candidate, name] : NamesOf(T())) {
        if (candidate == value) (*object_)[key] = name;
      }
    } else if constexpr (std::is_same_v<T, std::vector<std::string>> ||
                         std::is_same_v<T, std::vector<int>>) {
      (*object_)[key] = value;
    } else if constexpr (std::is_class_v<T> && !std::is_same_v<T, std::string>) {
      json nested = json::object();
      Writer writer(&nested);
      VisitFields(value, writer);
      (*object_)[key] = std::move(nested);
    } else {
      (*object_)[key] = value;
    }
  }

 private:
  json* object_;
};

}  // namespace

Status LoadConfigFile(const std::string& path, nlohmann::json* config) {
  std::ifstream in(path);
  if (!in) return Status::Error(path + ": cannot open");
  std::ostringstream text;
  text << in.rdbuf();
  if (in.bad()) return Status::Error(path + ": read failed");
  try {
    *config = json::parse(text.str(),
                          /*cb=*/nullptr,
                          /*allow_exceptions=*/true,
                          /*ignore_comments=*/true);
  } catch (const json::parse_error& e) {
    // e.what() is "[json.exception.parse_error.101] parse error at line 3, column 7: ...".
    std::string message = e.what();
    if (const size_t end = message.find("] "); end != std::string::npos) {
      message = message.substr(end + 2);
    }
    return Status::Error(path + ": " + message);
  }
  return Status::Ok();
}

Status ParseIrrrOptions(const nlohmann::json& irrr_section,
                        IrrrOptions* options,
                        const std::string& path) {
  IrrrOptions parsed = *options;
  Reader reader(irrr_section, path);
  if (Status s = reader.Read(&parsed); !s.ok()) return s;
  if (Status s = parsed.Validate(); !s.ok()) return Status::Error(path + ": " + s.message());
  *options = parsed;
  return Status::Ok();
}

Status ParseIrrrConfig(const nlohmann::json& config, IrrrOptions* options) {
  if (!config.is_object()) {
    return Status::Error("configuration: expected an object, got " + Quote(config));
  }
  const auto it = config.find("irrr");
  if (it == config.end()) return Status::Ok();
  return ParseIrrrOptions(*it, options, "irrr");
}

nlohmann::json IrrrOptionsToJson(const IrrrOptions& options) {
  json object = json::object();
  Writer writer(&object);
  IrrrOptions copy = options;
  VisitFields(copy, writer);
  return object;
}

Status DaemonOptions::Validate() const {
  if (daemon_id.empty() || daemon_id.size() > 64) {
    return Status::Error("daemon_id: must have 1 to 64 characters");
  }
  static const std::set<std::string> levels = {
      "trace", "debug", "info", "warn", "error", "critical", "off"};
  if (levels.count(log_level) == 0) {
    return Status::Error(
        "log_level: expected trace, debug, info, warn, error, critical or off, "
        "got \"" +
        log_level + "\"");
  }
  if (!(status_hz > 0.0 && status_hz <= 100.0)) {
    return Status::Error("status_hz: must be in (0, 100], got " + std::to_string(status_hz));
  }
  std::set<std::string> names;
  DaemonChannels copy = channels;
  Status status = Status::Ok();
  auto check_channel = [&](const char* key, const std::string& name) {
    if (!status.ok()) return;
    if (name.empty()) status = Status::Error(std::string("channels.") + key + ": empty");
    if (!names.insert(name).second) {
      status = Status::Error(std::string("channels.") + key + ": \"" + name +
                             "\" is used by another channel too");
    }
  };
  VisitFields(copy, check_channel);
  if (!status.ok()) return status;
  if (limits.queue_limit < 1 || limits.max_message_bytes < 1024 || limits.max_sessions < 1 ||
      limits.max_keyframes < 1 || limits.max_hypotheses < 0 || limits.max_parked < 0 ||
      limits.max_held < 0) {
    return Status::Error(
        "limits: queue_limit, max_sessions and max_keyframes must be >= 1, "
        "max_message_bytes >= 1024, max_hypotheses, max_parked and max_held >= 0");
  }
  if (resync.interval_ms < 1 || resync.give_up_ms < resync.interval_ms) {
    return Status::Error("resync: interval_ms must be >= 1 and give_up_ms >= interval_ms");
  }
  if (journal.snapshot_every < 0) return Status::Error("journal: snapshot_every must be >= 0");
  if (!(journal.snapshot_after_s >= 0.0 && std::isfinite(journal.snapshot_after_s))) {
    return Status::Error("journal: snapshot_after_s must be finite and >= 0");
  }
  if (!(journal.compact_mb >= 0.0 && std::isfinite(journal.compact_mb))) {
    return Status::Error("journal: compact_mb must be finite and >= 0");
  }
  if (merge.window_ms < 0) return Status::Error("merge: window_ms must be >= 0");
  for (const std::string& sender : merge.senders) {
    if (sender.empty() || sender.size() > 64) {
      return Status::Error("merge.senders: \"" + sender + "\" must have 1 to 64 characters");
    }
  }
  for (const std::string& sender : allowed_senders) {
    if (sender.empty() || sender.size() > 64) {
      return Status::Error("allowed_senders: \"" + sender + "\" must have 1 to 64 characters");
    }
  }
  for (int robot : allowed_robots) {
    if (robot < 0)
      return Status::Error("allowed_robots: negative robot id " + std::to_string(robot));
  }
  return Status::Ok();
}

Status ParseDaemonConfig(const nlohmann::json& config,
                         DaemonOptions* daemon,
                         IrrrOptions* options) {
  if (!config.is_object()) {
    return Status::Error("configuration: expected an object, got " + Quote(config));
  }
  for (const auto& item : config.items()) {
    if (item.key() != "daemon" && item.key() != "irrr") {
      return Status::Error(item.key() + ": unknown key (known: daemon, irrr)");
    }
  }
  DaemonOptions parsed_daemon = *daemon;
  if (const auto it = config.find("daemon"); it != config.end()) {
    Reader reader(*it, "daemon");
    if (Status s = reader.Read(&parsed_daemon); !s.ok()) return s;
    if (Status s = parsed_daemon.Validate(); !s.ok()) return Status::Error("daemon." + s.message());
  }
  IrrrOptions parsed_options = *options;
  if (Status s = ParseIrrrConfig(config, &parsed_options); !s.ok()) return s;
  *daemon = parsed_daemon;
  *options = parsed_options;
  return Status::Ok();
}

Status LoadDaemonConfig(const std::string& path, DaemonOptions* daemon, IrrrOptions* options) {
  json config;
  if (Status s = LoadConfigFile(path, &config); !s.ok()) return s;
  if (Status s = ParseDaemonConfig(config, daemon, options); !s.ok()) {
    return Status::Error(path + ": " + s.message());
  }
  return Status::Ok();
}

Status LoadClientConfig(const std::string& path, DaemonOptions* daemon, std::string* lcm_url) {
  if (!path.empty()) {
    IrrrOptions options;
    if (Status s = LoadDaemonConfig(path, daemon, &options); !s.ok()) return s;
  }
  if (lcm_url->empty()) *lcm_url = daemon->lcm_url;
  return Status::Ok();
}

nlohmann::json DaemonOptionsToJson(const DaemonOptions& options) {
  json object = json::object();
  Writer writer(&object);
  DaemonOptions copy = options;
  VisitFields(copy, writer);
  return object;
}

}  // namespace irrr
