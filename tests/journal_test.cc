// The journal (daemon/journal.h): records come back as written, torn or corrupt tails dropped.

#include <fcntl.h>
#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <functional>
#include <limits>
#include <map>
#include <memory>
#include <mutex>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include <fmt/core.h>
#include <spdlog/spdlog.h>
#include <catch2/catch.hpp>
#include <lcm/lcm-cpp.hpp>

#include "clients/common/graph_files.h"
#include "clients/common/loop_csv.h"
#include "clients/common/replay_messages.h"
#include "core/irrr.h"
#include "daemon/common/irrr_config.h"
#include "daemon/journal.h"
#include "daemon/raw_subscription.h"
#include "daemon/sequencer.h"
#include "daemon/service.h"
#include "daemon/snapshot.h"
#include "daemon/stamp_merger.h"
#include "daemon/wire.h"
#include "irrr/correction_t.hpp"
#include "irrr/error_t.hpp"
#include "irrr/resync_request_t.hpp"
#include "irrr/solution_request_t.hpp"
#include "irrr/solution_t.hpp"
#include "irrr/verdicts_t.hpp"
#include "tests/recording_sink.h"
#include "tests/service_helpers.h"
#include "tests/test_files.h"

namespace irrr {
namespace {

using Catch::Matchers::Contains;
using Clock = std::chrono::steady_clock;

JournalRecord Record(uint8_t fill, size_t size) {
  JournalRecord r;
  r.kind = static_cast<JournalRecord::Kind>(fill % 3);
  r.received_utime = 1000 + fill;
  r.bytes.assign(size, fill);
  return r;
}

int64_t FileSize(const std::string& path) {
  std::FILE* f = std::fopen(path.c_str(), "rb");
  REQUIRE(f != nullptr);
  std::fseek(f, 0, SEEK_END);
  const int64_t size = std::ftell(f);
  std::fclose(f);
  return size;
}

TEST_CASE("Journal: a batch's append names the CRC after each of its records", "[reliability]") {
  const std::string path = TestDirectory("journal_batch_crc") + "/journal";
  std::remove(path.c_str());
  Journal journal;
  JournalRecovery recovery;
  REQUIRE(journal.Open(path, JournalSyncPolicy::kNever, &recovery).ok());
  std::vector<JournalRecord> all;
  for (uint8_t k = 0; k < 3; ++k) all.push_back(Record(k, 5 + k));
  REQUIRE(journal.Append(all).ok());
  std::vector<JournalRecord> batch;
  for (uint8_t k = 3; k < 8; ++k) batch.push_back(Record(k, 40 - 3 * k));
  std::vector<uint32_t> crc_after;
  REQUIRE(journal.Append(batch, &crc_after).ok());
  all.insert(all.end(), batch.begin(), batch.end());
  REQUIRE(crc_after.size() == batch.size());
  // Each is the CRC a journal holding exactly the records up to it has (what a snapshot names).
  for (size_t k = 0; k < batch.size(); ++k) {
    INFO("record " << 3 + k);
    CHECK(crc_after[k] == JournalCrc(all, 3 + k + 1));
  }
  CHECK(crc_after.back() == journal.crc());
  CHECK(crc_after.front() != JournalCrc(all, 3));
}

TEST_CASE("Journal: compacted, it starts again empty and goes on numbering and naming records",
          "[reliability]") {
  const std::string dir = TestDirectory("journal_compact");
  const std::string path = dir + "/journal";
  const std::string archive = path + ".0-3";
  for (const std::string& p : {path, archive}) std::remove(p.c_str());
  std::vector<JournalRecord> all;
  for (uint8_t k = 0; k < 5; ++k) all.push_back(Record(k, 7 + k));
  Journal journal;
  JournalRecovery recovery;
  REQUIRE(journal.Open(path, JournalSyncPolicy::kBatch, &recovery).ok());
  REQUIRE(journal.Append({all[0], all[1], all[2]}).ok());
  const int64_t old_size = journal.size_bytes();
  REQUIRE(journal.Compact(archive).ok());
  CHECK(journal.records() == 3);
  CHECK(journal.first_record() == 3);
  CHECK(journal.crc() == JournalCrc(all, 3));
  CHECK(journal.size_bytes() == 20);
  CHECK(FileSize(path) == 20);
  REQUIRE(journal.Append({all[3], all[4]}).ok());
  CHECK(journal.crc() == JournalCrc(all, 5));

  // Read back: the records after the compaction, numbered from 3, with the CRC before them.
  Journal reopened;
  REQUIRE(reopened.Open(path, JournalSyncPolicy::kNever, &recovery).ok());
  CHECK(recovery.first_record == 3);
  CHECK(recovery.crc_before == JournalCrc(all, 3));
  REQUIRE(recovery.records.size() == 2);
  CHECK(recovery.records[1].bytes == all[4].bytes);
  CHECK(JournalCrc(recovery, 5) == JournalCrc(all, 5));
  CHECK(JournalCrc(recovery, 3) == JournalCrc(all, 3));
  CHECK(reopened.records() == 5);
  CHECK(reopened.crc() == journal.crc());

  // The archive is the journal as it was before: records 0 to 2.
  Journal old;
  REQUIRE(old.Open(archive, JournalSyncPolicy::kNever, &recovery).ok());
  CHECK(FileSize(archive) == old_size);
  CHECK(recovery.first_record == 0);
  REQUIRE(recovery.records.size() == 3);
  CHECK(recovery.records[2].bytes == all[2].bytes);
  CHECK(old.crc() == JournalCrc(all, 3));
}

TEST_CASE("Journal: records come back as written; a torn or corrupt tail is dropped",
          "[reliability]") {
  const std::string dir = TestDirectory("journal");
  const std::string path = dir + "/journal";
  std::remove(path.c_str());
  std::vector<JournalRecord> written;
  std::vector<int64_t> ends;  // file size after each record
  {
    Journal journal;
    JournalRecovery recovery;
    REQUIRE(journal.Open(path, JournalSyncPolicy::kNever, &recovery).ok());
    CHECK(recovery.records.empty());
    for (uint8_t k = 0; k < 20; ++k) {
      written.push_back(Record(k, 10 + 7 * k));
      REQUIRE(journal.Append({written.back()}).ok());
      ends.push_back(journal.size_bytes());
    }
  }
  CHECK(FileSize(path) == ends.back());
  auto reopen = [&](JournalRecovery* recovery) {
    Journal journal;
    const Status s = journal.Open(path, JournalSyncPolicy::kBatch, recovery);
    INFO(s.message());
    REQUIRE(s.ok());
  };
  JournalRecovery recovery;
  reopen(&recovery);
  REQUIRE(recovery.records.size() == written.size());
  for (size_t k = 0; k < written.size(); ++k) {
    CHECK(recovery.records[k].kind == written[k].kind);
    CHECK(recovery.records[k].received_utime == written[k].received_utime);
    CHECK(recovery.records[k].bytes == written[k].bytes);
  }
  CHECK(recovery.dropped_bytes == 0);

  // A crash in the middle of the last write: every cut inside the last record.
  const int64_t last_start = ends[ends.size() - 2];
  for (int64_t cut = last_start + 1; cut < ends.back(); cut += 5) {
    REQUIRE(truncate(path.c_str(), cut) == 0);
    reopen(&recovery);
    INFO("cut at " << cut);
    CHECK(recovery.records.size() == written.size() - 1);
    CHECK(recovery.dropped_bytes == cut - last_start);
    CHECK(FileSize(path) == last_start);  // truncated away
    // Appending goes on from there, readable.
    {
      Journal journal;
      JournalRecovery unused;
      REQUIRE(journal.Open(path, JournalSyncPolicy::kNever, &unused).ok());
      REQUIRE(journal.Append({written.back()}).ok());
    }
    reopen(&recovery);
    CHECK(recovery.records.size() == written.size());
    CHECK(recovery.dropped_bytes == 0);
  }

  // A flipped byte in record 12: it and everything after are dropped, with the reason.
  {
    const int fd = open(path.c_str(), O_RDWR);
    REQUIRE(fd >= 0);
    const off_t at = static_cast<off_t>(ends[11] + 20);
    uint8_t byte = 0;
    REQUIRE(pread(fd, &byte, 1, at) == 1);
    byte ^= 0x40;
    REQUIRE(pwrite(fd, &byte, 1, at) == 1);
    close(fd);
  }
  reopen(&recovery);
  CHECK(recovery.records.size() == 12);
  CHECK(recovery.dropped_bytes == ends.back() - ends[11]);
  CHECK_THAT(recovery.dropped_reason, Contains("CRC"));

  // Not a journal: refused, untouched.
  WriteText(dir + "/other", "hello world, not a journal");
  Journal journal;
  const Status s = journal.Open(dir + "/other", JournalSyncPolicy::kNever, &recovery);
  CHECK_FALSE(s.ok());
  CHECK_THAT(s.message(), Contains("not an irrrd journal"));
  CHECK(ReadText(dir + "/other") == "hello world, not a journal");
}

}  // namespace
}  // namespace irrr
