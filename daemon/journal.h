#ifndef IRRR_DAEMON_JOURNAL_H_
#define IRRR_DAEMON_JOURNAL_H_

// The daemon's journal: every input it takes, in the order it applies them, appended before they
// are applied, so that a restart replays exactly the same sequence and rebuilds the same state.
//
// File: a header, then records, each
//   uint32 payload length | uint32 CRC-32 (zlib) of the payload | payload
//   payload = uint8 channel kind | int64 received_utime | the LCM-encoded message
// in little-endian byte order. A record that is cut short or fails its CRC ends the journal: a
// crash can tear only the last write, so everything from there on is dropped (and truncated
// away) with a log line.
//
// Records are numbered from the first input the map ever took. A journal that holds them all
// starts with the 8 bytes "IRRRJNL1"; a compacted one (Compact: the inputs before it are in the
// daemon's base, service_state.h) with "IRRRJNL2" | int64 number of its first record | uint32
// the CRC of the records before it. The CRC that names a prefix (Journal::crc, JournalCrc) runs
// over every record from the first, across compactions.

#include <cstdint>
#include <string>
#include <vector>

#include "core/status.h"
#include "daemon/common/irrr_config.h"

namespace irrr {

struct JournalRecord {
  enum Kind : uint8_t { kKeyframe = 0, kLoop = 1, kSession = 2 };
  Kind kind = kKeyframe;
  int64_t received_utime = 0;
  std::vector<uint8_t> bytes;  // the message as received
};

// What Open found.
struct JournalRecovery {
  int64_t first_record = 0;  // the number of records[0] (0 unless compacted)
  uint32_t crc_before = 0;   // the CRC of the records before it (EmptyJournalCrc() if none)
  std::vector<JournalRecord> records;
  int64_t valid_bytes = 0;    // the journal's length after recovery
  int64_t dropped_bytes = 0;  // a torn or corrupt tail, truncated away
  std::string dropped_reason;
};

class Journal {
 public:
  Journal() = default;
  ~Journal();
  Journal(const Journal&) = delete;
  Journal& operator=(const Journal&) = delete;

  // `sync` says when appended records reach the disk. A process crash, kill -9 included, loses
  // nothing written under any policy; the policy is about power loss and kernel crashes: kNever
  // leaves write-back to the kernel, kBatch calls fdatasync after each Append (the worker appends
  // a batch before applying it), kAlways after every record.
  // Opens (creating it if missing) the journal at `path`, reads back every valid record into
  // `recovery`, truncates a torn tail, and positions for appending.
  Status Open(const std::string& path, JournalSyncPolicy sync, JournalRecovery* recovery);
  // Appends records (one write), then syncs per the policy. `crc_after`, when given, gets the
  // journal's CRC after each of them: what names a prefix that ends inside the batch (a snapshot
  // taken before the whole batch is applied).
  Status Append(const std::vector<JournalRecord>& records,
                std::vector<uint32_t>* crc_after = nullptr);
  // Starts the journal again, empty, after the records it holds: they are covered by a base the
  // caller has written. The file is replaced atomically (a crash leaves the old or the new one).
  // With `archive` non-empty, the records are first appended to that file (a journal of its own,
  // created with this one's header), so that the inputs' history stays whole.
  Status Compact(const std::string& archive);
  int64_t size_bytes() const { return size_; }
  const std::string& path() const { return path_; }
  // The records taken since the map began (compacted ones included), and the CRC-32 of all of
  // them as stored: what names a prefix for a snapshot or a base (JournalCrc).
  int64_t records() const { return records_; }
  uint32_t crc() const { return crc_; }
  // The number of the first record the file holds.
  int64_t first_record() const { return first_record_; }

 private:
  // Writes whole records (undoing a partial write), counts them, and takes `crc` (the journal's
  // CRC after them, computed by Append record by record) as its CRC.
  Status Write(const std::vector<uint8_t>& bytes, int64_t records, uint32_t crc);

  int fd_ = -1;
  std::string path_;
  JournalSyncPolicy sync_ = JournalSyncPolicy::kBatch;
  int64_t size_ = 0;
  int64_t header_bytes_ = 0;
  int64_t first_record_ = 0;
  int64_t records_ = 0;
  uint32_t crc_ = 0;
};

// Makes a rename into `path`'s directory reach the disk (fsyncs the directory; a failure to open
// it is ignored: the rename stays atomic for a process crash).
void SyncDirectoryOf(const std::string& path);

// Encodes one record (length, CRC, payload), and decodes the records at the start of `data`
// (stops at the first incomplete or corrupt one; `*consumed` = bytes of the valid records).
std::vector<uint8_t> EncodeJournalRecord(const JournalRecord& record);
// The CRC of no records.
uint32_t EmptyJournalCrc();
// CRC-32 of the first `count` of `records` as a journal stores them, continuing `before` (the CRC
// of the records before them): Journal::crc() after them.
uint32_t JournalCrc(const std::vector<JournalRecord>& records,
                    size_t count,
                    uint32_t before = EmptyJournalCrc());
// The same for a recovered journal: the CRC after its records numbered below `end`
// (first_record <= end <= first_record + records.size()).
uint32_t JournalCrc(const JournalRecovery& journal, int64_t end);
std::vector<JournalRecord> DecodeJournalRecords(const std::vector<uint8_t>& data,
                                                size_t begin,
                                                size_t* consumed,
                                                std::string* stop_reason);

}  // namespace irrr

#endif  // IRRR_DAEMON_JOURNAL_H_
