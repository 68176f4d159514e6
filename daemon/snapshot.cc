#include "daemon/snapshot.h"

#include <fcntl.h>
#include <unistd.h>
#include <zlib.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <limits>

#include "daemon/journal.h"

namespace irrr {
namespace {

constexpr char kMagic[8] = {'I', 'R', 'R', 'R', 'S', 'N', 'P', '6'};
constexpr char kBaseMagic[8] = {'I', 'R', 'R', 'R', 'B', 'A', 'S', '1'};
constexpr size_t kHeader = sizeof kMagic + 8;  // magic, length, CRC

const char* MagicOf(SnapshotKind kind) { return kind == SnapshotKind::kBase ? kBaseMagic : kMagic; }

// The kinds of input in SnapshotWriter::Inputs.
enum InputKind : int64_t { kFirstPose = 0, kPose = 1, kLoop = 2, kEndSession = 3, kFlush = 4 };
constexpr uint32_t kMaxBody = 1u << 31;

void PutU32(uint32_t v, std::vector<uint8_t>* out) {
  for (int k = 0; k < 4; ++k) out->push_back(static_cast<uint8_t>(v >> (8 * k)));
}
uint32_t GetU32(const uint8_t* p) {
  uint32_t v = 0;
  for (int k = 0; k < 4; ++k) v |= uint32_t{p[k]} << (8 * k);
  return v;
}
uint32_t Crc32(const uint8_t* data, size_t size) {
  return static_cast<uint32_t>(crc32(crc32(0L, Z_NULL, 0), data, static_cast<uInt>(size)));
}

Status Errno(const std::string& what) { return Status::Error(what + ": " + std::strerror(errno)); }

Status WriteAll(int fd, const uint8_t* data, size_t size, const std::string& path) {
  while (size > 0) {
    const ssize_t n = write(fd, data, size);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) return Errno(path + ": write");
    data += n;
    size -= static_cast<size_t>(n);
  }
  return Status::Ok();
}

}  // namespace

// ---- Writer ----

void SnapshotWriter::I64(int64_t v) {
  for (int k = 0; k < 8; ++k)
    bytes_.push_back(static_cast<uint8_t>(static_cast<uint64_t>(v) >> (8 * k)));
}

void SnapshotWriter::F64(double v) {
  uint64_t bits = 0;
  std::memcpy(&bits, &v, sizeof bits);
  I64(static_cast<int64_t>(bits));
}

void SnapshotWriter::String(const std::string& s) {
  I64(static_cast<int64_t>(s.size()));
  bytes_.insert(bytes_.end(), s.begin(), s.end());
}

void SnapshotWriter::Ints(const std::vector<int>& v) {
  I64(static_cast<int64_t>(v.size()));
  for (int x : v) I64(x);
}

template <>
void SnapshotWriter::PoseValue(const Pose2& pose) {
  F64(pose.translation().x());
  F64(pose.translation().y());
  F64(pose.yaw_rad());
}

template <>
void SnapshotWriter::PoseValue(const Pose3& pose) {
  const Eigen::Quaterniond& q = pose.quaternion();
  for (double v : {q.w(), q.x(), q.y(), q.z()}) F64(v);
  for (int k = 0; k < 3; ++k) F64(pose.translation()[k]);
}

template <class Pose>
void SnapshotWriter::StepState(const IrrrStepState<Pose>& state) {
  I64(static_cast<int64_t>(state.decisions.size()));
  for (const LoopDecision& d : state.decisions) {
    I64(d.cluster);
    I64(static_cast<int64_t>(d.state));
    I64(d.step);
    F64(d.chi2);
    F64(d.threshold);
  }
  I64(static_cast<int64_t>(state.estimate.size()));
  for (const Pose& pose : state.estimate) PoseValue(pose);
  I64(static_cast<int64_t>(state.clusters.size()));
  for (const auto& c : state.clusters) {
    Ints(c.links);
    I64(c.session_a);
    I64(c.session_b);
    I64((c.in_r ? 1 : 0) | (c.in_good ? 2 : 0) | (c.in_reject ? 4 : 0) | (c.closed ? 8 : 0) |
        (c.held ? 16 : 0) | (c.deferred ? 32 : 0));
    Ints(c.opponents);
    F64(c.redundancy_chi2);
    F64(c.redundancy_dof);
    F64(c.accepted_variance);
    F64(c.refused_variance);
    I64(c.checked_links);
    F64(c.checked_variance);
  }
  Ints(state.cluster_of);
  I64(state.steps);
  I64(state.judged);
  Ints(state.weakened_odometry);
}

template <class Pose>
void SnapshotWriter::InformationValue(const typename Pose::Matrix& information) {
  for (int r = 0; r < Pose::kDim; ++r) {
    for (int c = 0; c < Pose::kDim; ++c) F64(information(r, c));
  }
}

template <class Pose>
void SnapshotWriter::Inputs(const Irrr<Pose>& irrr) {
  const PoseGraph<Pose>& graph = irrr.graph();
  const std::vector<ArrivalEvent>& arrivals = irrr.Arrivals();
  I64(static_cast<int64_t>(arrivals.size()));
  for (const ArrivalEvent& event : arrivals) {
    switch (event.kind) {
      case ArrivalEvent::Kind::kPose: {
        const Vertex& vertex = graph.vertex(event.index);
        const int odometry = graph.OdometryInto(event.index);
        I64(odometry < 0 ? kFirstPose : kPose);
        I64(vertex.session);
        if (odometry < 0) I64(graph.session(vertex.session).id);
        I64(vertex.id);
        F64(vertex.stamp);
        if (odometry >= 0) {
          PoseValue(graph.edge(odometry).measurement);
          InformationValue<Pose>(irrr.GivenInformation(odometry));
        }
        break;
      }
      case ArrivalEvent::Kind::kLoop: {
        const Edge<Pose>& edge = graph.edge(event.index);
        I64(kLoop);
        I64(edge.from);
        I64(edge.to);
        PoseValue(edge.measurement);
        InformationValue<Pose>(irrr.GivenInformation(event.index));
        break;
      }
      case ArrivalEvent::Kind::kEndSession:
        I64(kEndSession);
        I64(event.index);
        break;
      case ArrivalEvent::Kind::kFlush:
        I64(kFlush);
        break;
    }
  }
}

// ---- Reader ----

bool SnapshotReader::I64(int64_t* v) {
  if (failed_ || body_.size() - at_ < 8) return !(failed_ = true);
  uint64_t bits = 0;
  for (int k = 0; k < 8; ++k) bits |= uint64_t{body_[at_ + k]} << (8 * k);
  at_ += 8;
  *v = static_cast<int64_t>(bits);
  return true;
}

bool SnapshotReader::F64(double* v) {
  int64_t bits = 0;
  if (!I64(&bits)) return false;
  std::memcpy(v, &bits, sizeof *v);
  return true;
}

bool SnapshotReader::Int(int* v) {
  int64_t wide = 0;
  if (!I64(&wide)) return false;
  if (wide < std::numeric_limits<int>::min() || wide > std::numeric_limits<int>::max()) {
    return !(failed_ = true);
  }
  *v = static_cast<int>(wide);
  return true;
}

bool SnapshotReader::Count(size_t min_bytes_each, size_t* count) {
  int64_t n = 0;
  if (!I64(&n)) return false;
  if (n < 0 || static_cast<uint64_t>(n) > (body_.size() - at_) / min_bytes_each) {
    return !(failed_ = true);
  }
  *count = static_cast<size_t>(n);
  return true;
}

bool SnapshotReader::String(std::string* s) {
  size_t n = 0;
  if (!Count(1, &n)) return false;
  s->assign(body_.begin() + static_cast<std::ptrdiff_t>(at_),
            body_.begin() + static_cast<std::ptrdiff_t>(at_ + n));
  at_ += n;
  return true;
}

bool SnapshotReader::Ints(std::vector<int>* v) {
  size_t n = 0;
  if (!Count(8, &n)) return false;
  v->resize(n);
  for (int& x : *v) {
    if (!Int(&x)) return false;
  }
  return true;
}

template <>
bool SnapshotReader::PoseValue(Pose2* pose) {
  double x = 0.0;
  double y = 0.0;
  double yaw = 0.0;
  if (!F64(&x) || !F64(&y) || !F64(&yaw)) return false;
  *pose = Pose2(x, y, yaw);
  return true;
}

template <>
bool SnapshotReader::PoseValue(Pose3* pose) {
  double v[7];
  for (double& x : v) {
    if (!F64(&x)) return false;
  }
  const Eigen::Quaterniond q(v[0], v[1], v[2], v[3]);
  if (!(std::abs(q.norm() - 1.0) < 1e-6)) return !(failed_ = true);
  *pose = Pose3(q, Eigen::Vector3d(v[4], v[5], v[6]));
  return true;
}

template <class Pose>
bool SnapshotReader::StepState(IrrrStepState<Pose>* state) {
  size_t n = 0;
  if (!Count(5 * 8, &n)) return false;
  state->decisions.resize(n);
  for (LoopDecision& d : state->decisions) {
    int kind = 0;
    if (!Int(&d.cluster) || !Int(&kind) || !Int(&d.step) || !F64(&d.chi2) || !F64(&d.threshold)) {
      return false;
    }
    if (kind < static_cast<int>(LoopState::kPending) ||
        kind > static_cast<int>(LoopState::kReversed)) {
      return !(failed_ = true);
    }
    d.state = static_cast<LoopState>(kind);
  }
  if (!Count(Pose::kDim * 8, &n)) return false;
  state->estimate.resize(n);
  for (Pose& pose : state->estimate) {
    if (!PoseValue(&pose)) return false;
  }
  if (!Count(12 * 8, &n)) return false;
  state->clusters.resize(n);
  for (auto& c : state->clusters) {
    int64_t flags = 0;
    if (!Ints(&c.links) || !Int(&c.session_a) || !Int(&c.session_b) || !I64(&flags) ||
        !Ints(&c.opponents) || !F64(&c.redundancy_chi2) || !F64(&c.redundancy_dof) ||
        !F64(&c.accepted_variance) || !F64(&c.refused_variance) || !Int(&c.checked_links) ||
        !F64(&c.checked_variance)) {
      return false;
    }
    c.closed = (flags & 8) != 0;
    c.in_r = (flags & 1) != 0;
    c.in_good = (flags & 2) != 0;
    c.in_reject = (flags & 4) != 0;
    c.held = (flags & 16) != 0;
    c.deferred = (flags & 32) != 0;
  }
  return Ints(&state->cluster_of) && Int(&state->steps) && Int(&state->judged) &&
         Ints(&state->weakened_odometry);
}

template <class Pose>
bool SnapshotReader::InformationValue(typename Pose::Matrix* information) {
  for (int r = 0; r < Pose::kDim; ++r) {
    for (int c = 0; c < Pose::kDim; ++c) {
      if (!F64(&(*information)(r, c))) return false;
    }
  }
  return true;
}

template <class Pose>
bool SnapshotReader::FeedInputs(Irrr<Pose>* irrr, const std::function<void()>& after_each) {
  size_t n = 0;
  if (!Count(8, &n)) return false;
  for (size_t k = 0; k < n; ++k) {
    int64_t kind = 0;
    if (!I64(&kind)) return false;
    Status fed = Status::Ok();
    switch (kind) {
      case kFirstPose:
      case kPose: {
        int session = -1;
        int64_t session_id = 0;
        int64_t vertex_id = 0;
        double stamp = 0.0;
        if (!Int(&session) || (kind == kFirstPose && !I64(&session_id)) || !I64(&vertex_id) ||
            !F64(&stamp)) {
          return false;
        }
        if (kind == kFirstPose) {
          int added = -1;
          fed = irrr->AddSession(session_id, &added);
          if (fed.ok() && added != session) return !(failed_ = true);
        }
        Pose odometry;
        typename Pose::Matrix information;
        if (kind == kPose && (!PoseValue(&odometry) || !InformationValue<Pose>(&information))) {
          return false;
        }
        if (fed.ok()) {
          fed = irrr->AddPose(session,
                              vertex_id,
                              stamp,
                              kind == kPose ? &odometry : nullptr,
                              kind == kPose ? &information : nullptr,
                              nullptr);
        }
        break;
      }
      case kLoop: {
        int from = -1;
        int to = -1;
        Pose measurement;
        typename Pose::Matrix information;
        if (!Int(&from) || !Int(&to) || !PoseValue(&measurement) ||
            !InformationValue<Pose>(&information)) {
          return false;
        }
        fed = irrr->AddLoop(from, to, measurement, information, nullptr);
        break;
      }
      case kEndSession: {
        int session = -1;
        if (!Int(&session)) return false;
        fed = irrr->EndSession(session);
        break;
      }
      case kFlush:
        irrr->Flush();
        break;
      default:
        return !(failed_ = true);
    }
    if (!fed.ok()) return !(failed_ = true);
    if (after_each) after_each();
  }
  return true;
}

// ---- Files ----

Status WriteSnapshotFile(const std::string& path,
                         const std::vector<uint8_t>& body,
                         JournalSyncPolicy sync,
                         SnapshotKind kind) {
  if (body.size() > kMaxBody) return Status::Error(path + ": snapshot too large");
  std::vector<uint8_t> header(MagicOf(kind), MagicOf(kind) + sizeof kMagic);
  PutU32(static_cast<uint32_t>(body.size()), &header);
  PutU32(Crc32(body.data(), body.size()), &header);
  const std::string tmp = path + ".tmp";
  const int fd = open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) return Errno(tmp);
  Status s = WriteAll(fd, header.data(), header.size(), tmp);
  if (s.ok()) s = WriteAll(fd, body.data(), body.size(), tmp);
  if (s.ok() && sync != JournalSyncPolicy::kNever && fdatasync(fd) != 0) s = Errno(tmp);
  if (close(fd) != 0 && s.ok()) s = Errno(tmp + ": close");
  if (s.ok() && std::rename(tmp.c_str(), path.c_str()) != 0) s = Errno(path + ": rename");
  if (!s.ok()) {
    std::remove(tmp.c_str());
    return s;
  }
  if (sync != JournalSyncPolicy::kNever) SyncDirectoryOf(path);
  return Status::Ok();
}

Status ReadSnapshotFile(const std::string& path,
                        std::vector<uint8_t>* body,
                        bool* exists,
                        SnapshotKind kind) {
  body->clear();
  *exists = false;
  const int fd = open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return errno == ENOENT ? Status::Ok() : Errno(path);
  *exists = true;
  std::vector<uint8_t> data;
  uint8_t buffer[1 << 16];
  for (;;) {
    const ssize_t n = read(fd, buffer, sizeof buffer);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) {
      close(fd);
      return Errno(path + ": read");
    }
    if (n == 0) break;
    data.insert(data.end(), buffer, buffer + n);
  }
  close(fd);
  if (data.size() < kHeader || std::memcmp(data.data(), MagicOf(kind), sizeof kMagic) != 0) {
    return Status::Error(path + ": not an irrrd " +
                         (kind == SnapshotKind::kBase ? "base" : "snapshot") +
                         " of this version (it does not start with " +
                         std::string(MagicOf(kind), sizeof kMagic) + ")");
  }
  const uint32_t length = GetU32(&data[sizeof kMagic]);
  const uint32_t crc = GetU32(&data[sizeof kMagic + 4]);
  if (data.size() - kHeader != length) {
    return Status::Error(path + ": " + std::to_string(data.size() - kHeader) +
                         " bytes of body, its header says " + std::to_string(length));
  }
  if (Crc32(&data[kHeader], length) != crc) return Status::Error(path + ": fails its CRC");
  body->assign(data.begin() + kHeader, data.end());
  return Status::Ok();
}

template void SnapshotWriter::StepState(const IrrrStepState<Pose2>&);
template void SnapshotWriter::StepState(const IrrrStepState<Pose3>&);
template bool SnapshotReader::StepState(IrrrStepState<Pose2>*);
template bool SnapshotReader::StepState(IrrrStepState<Pose3>*);
template void SnapshotWriter::Inputs(const Irrr<Pose2>&);
template void SnapshotWriter::Inputs(const Irrr<Pose3>&);
template bool SnapshotReader::FeedInputs(Irrr<Pose2>*, const std::function<void()>&);
template bool SnapshotReader::FeedInputs(Irrr<Pose3>*, const std::function<void()>&);

}  // namespace irrr
