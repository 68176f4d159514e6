#include "daemon/journal.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>
#include <zlib.h>

#include <cerrno>
#include <cstring>

namespace irrr {
namespace {

constexpr char kMagic[8] = {'I', 'R', 'R', 'R', 'J', 'N', 'L', '1'};
constexpr char kCompactedMagic[8] = {'I', 'R', 'R', 'R', 'J', 'N', 'L', '2'};
constexpr size_t kCompactedHeader = 8 + 8 + 4;  // magic, first record, CRC before
constexpr size_t kRecordHeader = 8;             // length + CRC
constexpr size_t kPayloadHeader = 1 + 8;        // kind + received_utime
constexpr uint32_t kMaxPayload = 64u << 20;

void PutU32(uint32_t v, std::vector<uint8_t>* out) {
  for (int k = 0; k < 4; ++k) out->push_back(static_cast<uint8_t>(v >> (8 * k)));
}
void PutI64(int64_t v, std::vector<uint8_t>* out) {
  for (int k = 0; k < 8; ++k)
    out->push_back(static_cast<uint8_t>(static_cast<uint64_t>(v) >> (8 * k)));
}
uint32_t GetU32(const uint8_t* p) {
  uint32_t v = 0;
  for (int k = 0; k < 4; ++k) v |= uint32_t{p[k]} << (8 * k);
  return v;
}
int64_t GetI64(const uint8_t* p) {
  uint64_t v = 0;
  for (int k = 0; k < 8; ++k) v |= uint64_t{p[k]} << (8 * k);
  return static_cast<int64_t>(v);
}

uint32_t ContinueCrc32(uint32_t crc, const uint8_t* data, size_t size) {
  return static_cast<uint32_t>(crc32(crc, data, static_cast<uInt>(size)));
}
uint32_t Crc32(const uint8_t* data, size_t size) {
  return ContinueCrc32(static_cast<uint32_t>(crc32(0L, Z_NULL, 0)), data, size);
}

Status Errno(const std::string& what) { return Status::Error(what + ": " + std::strerror(errno)); }

Status WriteAll(int fd, const uint8_t* data, size_t size) {
  while (size > 0) {
    const ssize_t n = write(fd, data, size);
    if (n < 0) {
      if (errno == EINTR) continue;
      return Errno("write");
    }
    data += n;
    size -= static_cast<size_t>(n);
  }
  return Status::Ok();
}

}  // namespace

void SyncDirectoryOf(const std::string& path) {
  const size_t slash = path.rfind('/');
  const std::string dir =
      slash == std::string::npos ? "." : (slash == 0 ? "/" : path.substr(0, slash));
  const int fd = open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd >= 0) {
    fsync(fd);
    close(fd);
  }
}

std::vector<uint8_t> EncodeJournalRecord(const JournalRecord& record) {
  std::vector<uint8_t> payload;
  payload.reserve(kPayloadHeader + record.bytes.size());
  payload.push_back(record.kind);
  PutI64(record.received_utime, &payload);
  payload.insert(payload.end(), record.bytes.begin(), record.bytes.end());
  std::vector<uint8_t> out;
  out.reserve(kRecordHeader + payload.size());
  PutU32(static_cast<uint32_t>(payload.size()), &out);
  PutU32(Crc32(payload.data(), payload.size()), &out);
  out.insert(out.end(), payload.begin(), payload.end());
  return out;
}

uint32_t EmptyJournalCrc() { return Crc32(nullptr, 0); }

uint32_t JournalCrc(const std::vector<JournalRecord>& records, size_t count, uint32_t before) {
  uint32_t crc = before;
  for (size_t k = 0; k < count && k < records.size(); ++k) {
    const std::vector<uint8_t> encoded = EncodeJournalRecord(records[k]);
    crc = ContinueCrc32(crc, encoded.data(), encoded.size());
  }
  return crc;
}

uint32_t JournalCrc(const JournalRecovery& journal, int64_t end) {
  IRRR_CHECK(end >= journal.first_record &&
             end - journal.first_record <= static_cast<int64_t>(journal.records.size()));
  return JournalCrc(
      journal.records, static_cast<size_t>(end - journal.first_record), journal.crc_before);
}

std::vector<JournalRecord> DecodeJournalRecords(const std::vector<uint8_t>& data,
                                                size_t begin,
                                                size_t* consumed,
                                                std::string* stop_reason) {
  std::vector<JournalRecord> records;
  size_t at = begin;
  stop_reason->clear();
  while (at < data.size()) {
    if (data.size() - at < kRecordHeader) {
      *stop_reason = "a record header cut short";
      break;
    }
    const uint32_t length = GetU32(&data[at]);
    const uint32_t crc = GetU32(&data[at + 4]);
    if (length < kPayloadHeader || length > kMaxPayload) {
      *stop_reason = "a record length of " + std::to_string(length) + " bytes";
      break;
    }
    if (data.size() - at - kRecordHeader < length) {
      *stop_reason = "a record cut short";
      break;
    }
    const uint8_t* payload = &data[at + kRecordHeader];
    if (Crc32(payload, length) != crc) {
      *stop_reason = "a record failing its CRC";
      break;
    }
    if (payload[0] > JournalRecord::kSession) {
      *stop_reason = "a record of unknown kind " + std::to_string(payload[0]);
      break;
    }
    JournalRecord r;
    r.kind = static_cast<JournalRecord::Kind>(payload[0]);
    r.received_utime = GetI64(payload + 1);
    r.bytes.assign(payload + kPayloadHeader, payload + length);
    records.push_back(std::move(r));
    at += kRecordHeader + length;
  }
  *consumed = at - begin;
  return records;
}

Journal::~Journal() {
  if (fd_ >= 0) close(fd_);
}

Status Journal::Open(const std::string& path, JournalSyncPolicy sync, JournalRecovery* recovery) {
  path_ = path;
  sync_ = sync;
  *recovery = JournalRecovery();
  first_record_ = 0;
  crc_ = EmptyJournalCrc();
  fd_ = open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (fd_ < 0) return Errno(path);
  std::vector<uint8_t> data;
  uint8_t buffer[1 << 16];
  for (;;) {
    const ssize_t n = read(fd_, buffer, sizeof buffer);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) return Errno(path + ": read");
    if (n == 0) break;
    data.insert(data.end(), buffer, buffer + n);
  }
  if (data.empty()) {
    if (Status s = WriteAll(fd_, reinterpret_cast<const uint8_t*>(kMagic), sizeof kMagic); !s.ok())
      return Status::Error(path + ": " + s.message());
    if (fdatasync(fd_) != 0) return Errno(path + ": fdatasync");
    size_ = header_bytes_ = sizeof kMagic;
    records_ = 0;
    recovery->crc_before = crc_;
    recovery->valid_bytes = size_;
    return Status::Ok();
  }
  if (data.size() >= sizeof kMagic && std::memcmp(data.data(), kMagic, sizeof kMagic) == 0) {
    header_bytes_ = sizeof kMagic;
  } else if (data.size() >= kCompactedHeader &&
             std::memcmp(data.data(), kCompactedMagic, sizeof kCompactedMagic) == 0) {
    header_bytes_ = kCompactedHeader;
    first_record_ = GetI64(&data[8]);
    crc_ = GetU32(&data[16]);
    if (first_record_ < 0) return Status::Error(path + ": its header numbers a negative record");
  } else {
    return Status::Error(path +
                         ": not an irrrd journal (it does not start with IRRRJNL1 or IRRRJNL2)");
  }
  recovery->first_record = first_record_;
  recovery->crc_before = crc_;
  size_t consumed = 0;
  recovery->records = DecodeJournalRecords(
      data, static_cast<size_t>(header_bytes_), &consumed, &recovery->dropped_reason);
  size_ = header_bytes_ + static_cast<int64_t>(consumed);
  records_ = first_record_ + static_cast<int64_t>(recovery->records.size());
  crc_ = ContinueCrc32(crc_, data.data() + header_bytes_, consumed);
  recovery->valid_bytes = size_;
  recovery->dropped_bytes = static_cast<int64_t>(data.size()) - size_;
  if (recovery->dropped_bytes > 0) {
    if (ftruncate(fd_, size_) != 0) return Errno(path + ": ftruncate");
    if (fdatasync(fd_) != 0) return Errno(path + ": fdatasync");
  }
  if (lseek(fd_, size_, SEEK_SET) < 0) return Errno(path + ": lseek");
  return Status::Ok();
}

Status Journal::Compact(const std::string& archive) {
  if (fd_ < 0) return Status::Error("journal: not open");
  const bool sync = sync_ != JournalSyncPolicy::kNever;
  const std::string tmp = path_ + ".tmp";
  std::vector<uint8_t> header(kCompactedMagic, kCompactedMagic + sizeof kCompactedMagic);
  PutI64(records_, &header);
  PutU32(crc_, &header);
  const int fd = open(tmp.c_str(), O_RDWR | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) return Errno(tmp);
  auto fail = [&](const Status& s) {
    close(fd);
    unlink(tmp.c_str());
    return s;
  };
  if (Status s = WriteAll(fd, header.data(), header.size()); !s.ok()) return fail(s);
  if (sync && fdatasync(fd) != 0) return fail(Errno(tmp + ": fdatasync"));
  // The old file stays whole under the archive's name (a second name for it, nothing copied).
  if (!archive.empty()) {
    unlink(archive.c_str());
    if (link(path_.c_str(), archive.c_str()) != 0) {
      return fail(Errno("link " + path_ + " " + archive));
    }
  }
  if (rename(tmp.c_str(), path_.c_str()) != 0) return fail(Errno("rename " + tmp + " " + path_));
  if (sync) SyncDirectoryOf(path_);
  close(fd_);
  fd_ = fd;
  size_ = header_bytes_ = static_cast<int64_t>(header.size());
  first_record_ = records_;
  if (lseek(fd_, size_, SEEK_SET) < 0) return Errno(path_ + ": lseek");
  return Status::Ok();
}

Status Journal::Write(const std::vector<uint8_t>& bytes, int64_t records, uint32_t crc) {
  if (Status s = WriteAll(fd_, bytes.data(), bytes.size()); !s.ok()) {
    // Cut a partial record off again, so that later appends stay readable.
    if (ftruncate(fd_, size_) != 0 || lseek(fd_, size_, SEEK_SET) < 0) {
      return Errno(path_ + ": cannot undo a partial write");
    }
    return Status::Error(path_ + ": " + s.message());
  }
  size_ += static_cast<int64_t>(bytes.size());
  records_ += records;
  crc_ = crc;
  return Status::Ok();
}

Status Journal::Append(const std::vector<JournalRecord>& records,
                       std::vector<uint32_t>* crc_after) {
  if (fd_ < 0) return Status::Error("journal: not open");
  if (crc_after != nullptr) crc_after->clear();
  if (records.empty()) return Status::Ok();
  std::vector<uint8_t> out;
  uint32_t crc = crc_;
  for (const JournalRecord& r : records) {
    const std::vector<uint8_t> encoded = EncodeJournalRecord(r);
    crc = ContinueCrc32(crc, encoded.data(), encoded.size());
    if (crc_after != nullptr) crc_after->push_back(crc);
    out.insert(out.end(), encoded.begin(), encoded.end());
    if (sync_ == JournalSyncPolicy::kAlways) {
      if (Status s = Write(out, 1, crc); !s.ok()) return s;
      if (fdatasync(fd_) != 0) return Errno(path_ + ": fdatasync");
      out.clear();
    }
  }
  if (!out.empty()) {
    if (Status s = Write(out, static_cast<int64_t>(records.size()), crc); !s.ok()) return s;
  }
  if (sync_ == JournalSyncPolicy::kBatch && fdatasync(fd_) != 0)
    return Errno(path_ + ": fdatasync");
  return Status::Ok();
}

}  // namespace irrr
