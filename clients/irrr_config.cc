#include "clients/irrr_config.h"

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
// one line here (and one in README's "Configuration"). Reading, writing and the list of known
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
  visit("alpha", options.alpha);
  visit("cluster_gap", options.cluster_gap);
  visit("graph_dof", options.graph_dof);
  visit("require_each_cluster_consistent", options.require_each_cluster_consistent);
  visit("prune_failing_clusters", options.prune_failing_clusters);
  visit("elimination_lookahead", options.elimination_lookahead);
  visit("split_failing_links", options.split_failing_links);
  visit("settle_undecided", options.settle_undecided);
  visit("revive_opponents", options.revive_opponents);
  visit("retry_within_step", options.retry_within_step);
  visit("local_problems", options.local_problems);
  visit("warm_start", options.warm_start);
  visit("optimizer", options.optimizer);
}

template <class Enum>
using EnumNames = std::vector<std::pair<Enum, const char*>>;

const EnumNames<GraphDegreesOfFreedom>& NamesOf(GraphDegreesOfFreedom) {
  static const EnumNames<GraphDegreesOfFreedom> names = {
      {GraphDegreesOfFreedom::kResidualRows, "residual_rows"},
      {GraphDegreesOfFreedom::kExact, "exact"},
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
    } else if constexpr (std::is_class_v<T>) {
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

}  // namespace irrr
