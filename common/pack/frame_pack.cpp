#include "common/pack/frame_pack.h"

#include <zstd.h>

#include <cstring>
#include <stdexcept>

namespace d3d {
namespace {
constexpr size_t kHeaderBytes = 16;  // uint32 count, rows, cols, type (little-endian host order)

void PutU32(std::string* s, size_t at, uint32_t v) { std::memcpy(s->data() + at, &v, 4); }
uint32_t GetU32(std::string_view s, size_t at) {
  uint32_t v;
  std::memcpy(&v, s.data() + at, 4);
  return v;
}
bool PackableType(int type) {
  const int depth = CV_MAT_DEPTH(type), channels = CV_MAT_CN(type);
  return (depth == CV_8U || depth == CV_16U || depth == CV_32F) && channels >= 1 && channels <= 4;
}
}  // namespace

FramePacker::FramePacker(int level) : ctx_(ZSTD_createCCtx()), level_(level) {
  if (level < 1 || level > 19) {
    ZSTD_freeCCtx(static_cast<ZSTD_CCtx*>(ctx_));
    throw std::invalid_argument("FramePacker: zstd level must be in [1, 19], got " +
                                std::to_string(level));
  }
  if (ctx_ == nullptr) throw std::runtime_error("FramePacker: ZSTD_createCCtx failed");
}

FramePacker::~FramePacker() { ZSTD_freeCCtx(static_cast<ZSTD_CCtx*>(ctx_)); }

Status FramePacker::Pack(const std::vector<cv::Mat>& frames, std::string* blob) {
  if (frames.empty() || frames.size() > 255)
    return InvalidArgument("pack: 1 to 255 frames, got " + std::to_string(frames.size()));
  const cv::Mat& f0 = frames[0];
  if (!PackableType(f0.type()))
    return InvalidArgument("pack: frames must be CV_8U, CV_16U or CV_32F with 1 to 4 channels");
  if (f0.empty()) return InvalidArgument("pack: empty frame");
  for (const cv::Mat& f : frames)
    if (f.size() != f0.size() || f.type() != f0.type())
      return InvalidArgument("pack: the frames differ in size or type");
  const size_t row_bytes = static_cast<size_t>(f0.cols) * f0.elemSize();
  const size_t frame_bytes = row_bytes * static_cast<size_t>(f0.rows);
  raw_.resize(frame_bytes * frames.size());
  for (size_t i = 0; i < frames.size(); ++i) {
    char* dst = raw_.data() + i * frame_bytes;
    if (frames[i].isContinuous()) {
      std::memcpy(dst, frames[i].data, frame_bytes);
    } else {
      for (int r = 0; r < f0.rows; ++r)
        std::memcpy(dst + static_cast<size_t>(r) * row_bytes, frames[i].ptr(r), row_bytes);
    }
  }
  blob->resize(kHeaderBytes + ZSTD_compressBound(raw_.size()));
  PutU32(blob, 0, static_cast<uint32_t>(frames.size()));
  PutU32(blob, 4, static_cast<uint32_t>(f0.rows));
  PutU32(blob, 8, static_cast<uint32_t>(f0.cols));
  PutU32(blob, 12, static_cast<uint32_t>(f0.type()));
  const size_t n = ZSTD_compressCCtx(static_cast<ZSTD_CCtx*>(ctx_), blob->data() + kHeaderBytes,
                                     blob->size() - kHeaderBytes, raw_.data(), raw_.size(), level_);
  if (ZSTD_isError(n)) {
    blob->clear();
    return Status(StatusCode::kInternal, std::string("pack: zstd: ") + ZSTD_getErrorName(n));
  }
  blob->resize(kHeaderBytes + n);
  return Status::Ok();
}

Status UnpackFrames(std::string_view blob, std::vector<cv::Mat>* frames) {
  if (blob.size() < kHeaderBytes)
    return Corrupt("unpack: the blob is cut off before its header ends");
  const uint32_t count = GetU32(blob, 0), rows = GetU32(blob, 4), cols = GetU32(blob, 8),
                 type = GetU32(blob, 12);
  if (count < 1 || count > 255 || rows < 1 || cols < 1 || rows > (1u << 15) || cols > (1u << 15) ||
      type > static_cast<uint32_t>(CV_MAKETYPE(CV_32F, 4)) || !PackableType(static_cast<int>(type)))
    return Corrupt("unpack: bad header");
  const size_t elem = CV_ELEM_SIZE(static_cast<int>(type));
  const size_t frame_bytes = size_t{rows} * cols * elem;
  const std::string_view data = blob.substr(kHeaderBytes);
  const unsigned long long content = ZSTD_getFrameContentSize(data.data(), data.size());
  if (content != frame_bytes * count)
    return Corrupt("unpack: the compressed size does not match the header");
  frames->resize(count);
  // Frames of one contiguous buffer would alias; each frame is decompressed into its own buffer
  // through a streaming context, in frame-sized pieces.
  ZSTD_DCtx* dctx = ZSTD_createDCtx();
  if (dctx == nullptr) return Status(StatusCode::kInternal, "unpack: ZSTD_createDCtx failed");
  ZSTD_inBuffer in{data.data(), data.size(), 0};
  Status status = Status::Ok();
  for (uint32_t i = 0; i < count && status.ok(); ++i) {
    cv::Mat& f = (*frames)[i];
    f.create(static_cast<int>(rows), static_cast<int>(cols), static_cast<int>(type));  // continuous
    ZSTD_outBuffer out{f.data, frame_bytes, 0};
    while (out.pos < out.size) {
      const size_t r = ZSTD_decompressStream(dctx, &out, &in);
      if (ZSTD_isError(r)) {
        status = Corrupt(std::string("unpack: zstd: ") + ZSTD_getErrorName(r));
        break;
      }
      if (out.pos < out.size && in.pos == in.size) {
        status = Corrupt("unpack: the compressed data ends early");
        break;
      }
    }
  }
  ZSTD_freeDCtx(dctx);
  if (!status.ok()) frames->clear();
  return status;
}

}  // namespace d3d
