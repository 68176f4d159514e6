#ifndef IRRR_CLIENTS_IRRR_CONFIG_H_
#define IRRR_CLIENTS_IRRR_CONFIG_H_

// The JSON configuration shared by irrr-batch and the daemon (config/irrrd.json). Its "irrr"
// object holds IrrrOptions; the other top-level objects belong to the daemon. Every key of the
// "irrr" object is optional, and the JSON names of all fields are listed once, in irrr_config.cc.
//
//   {
//     "irrr": {
//       "alpha": 0.95, "cluster_gap": 50, "graph_dof": "residual_rows",
//       "require_each_cluster_consistent": true, "prune_failing_clusters": true,
//       "elimination_lookahead": 3,
//       "optimizer": {"algorithm": "gauss_newton", "max_iterations": 100, ...}
//     }
//   }

#include <string>

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

}  // namespace irrr

#endif  // IRRR_CLIENTS_IRRR_CONFIG_H_
