#include "firmware/update/image_format.h"

#include <fcntl.h>
#include <sodium.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <charconv>
#include <cstring>
#include <fstream>
#include <mutex>
#include <sstream>
#include <stdexcept>

#include "firmware/update/little_endian.h"

namespace d3d::fw {

namespace {

bool AllZero(const uint8_t* p, size_t n) {
  return std::all_of(p, p + n, [](uint8_t b) { return b == 0; });
}

std::string HwHex(uint32_t id) {
  char buf[16];
  std::snprintf(buf, sizeof(buf), "0x%04x", id);
  return buf;
}

constexpr size_t kChunkBytes = 64 * 1024;

}  // namespace

void EnsureSodium() {
  static std::once_flag once;
  static int rc = 0;
  std::call_once(once, [] { rc = sodium_init(); });
  if (rc < 0) throw std::runtime_error("libsodium: sodium_init failed");
}

std::string SemVer::ToString() const {
  std::string s = std::to_string(major);
  s.append(".").append(std::to_string(minor)).append(".").append(std::to_string(patch));
  return s;
}

bool SemVer::Parse(std::string_view text, SemVer* out) {
  uint16_t parts[3];
  size_t pos = 0;
  for (int i = 0; i < 3; ++i) {
    const size_t end = i < 2 ? text.find('.', pos) : text.size();
    if (end == std::string_view::npos || end == pos) return false;
    unsigned v = 0;
    const auto r = std::from_chars(text.data() + pos, text.data() + end, v);
    if (r.ec != std::errc() || r.ptr != text.data() + end || v > 65535) return false;
    parts[i] = static_cast<uint16_t>(v);
    pos = end + 1;
  }
  *out = SemVer{parts[0], parts[1], parts[2]};
  return true;
}

std::array<uint8_t, kHeaderBytes> ImageHeader::Serialize() const {
  std::array<uint8_t, kHeaderBytes> h{};
  std::copy(kImageMagic.begin(), kImageMagic.end(), h.begin());
  PutLe16(&h[8], format_version);
  PutLe16(&h[10], static_cast<uint16_t>(kHeaderBytes));
  PutLe32(&h[12], hw_id);
  PutLe16(&h[16], version.major);
  PutLe16(&h[18], version.minor);
  PutLe16(&h[20], version.patch);
  PutLe32(&h[24], security_counter);
  PutLe64(&h[32], payload_size);
  std::copy(payload_sha256.begin(), payload_sha256.end(), h.begin() + 40);
  std::copy(key_id.begin(), key_id.end(), h.begin() + 72);
  return h;
}

uint64_t ImageHeader::ImageSize() const {
  if (payload_size > UINT64_MAX - kImageOverheadBytes) return UINT64_MAX;
  return payload_size + kImageOverheadBytes;
}

const char* RejectToken(Reject r) {
  switch (r) {
    case Reject::kNone:
      return "ok";
    case Reject::kTooShort:
      return "too-short";
    case Reject::kBadMagic:
      return "bad-magic";
    case Reject::kUnsupportedFormat:
      return "unsupported-format";
    case Reject::kBadHeader:
      return "bad-header";
    case Reject::kWrongHardware:
      return "wrong-hardware";
    case Reject::kOversize:
      return "oversize";
    case Reject::kDowngrade:
      return "downgrade";
    case Reject::kTruncated:
      return "truncated";
    case Reject::kTrailingData:
      return "trailing-data";
    case Reject::kPayloadHash:
      return "payload-hash";
    case Reject::kUnsigned:
      return "unsigned";
    case Reject::kUnknownKey:
      return "unknown-key";
    case Reject::kBadSignature:
      return "bad-signature";
  }
  return "unknown";
}

uint8_t DfuStatusFor(Reject r) {
  // Values of dfu::DfuStatus (dfu_protocol.h); kept numeric so this library needs no DFU header.
  switch (r) {
    case Reject::kNone:
      return 0x00;  // OK
    case Reject::kTooShort:
      return 0x09;  // errNOTDONE
    case Reject::kBadMagic:
      return 0x01;  // errTARGET
    case Reject::kUnsupportedFormat:
      return 0x01;  // errTARGET
    case Reject::kBadHeader:
      return 0x02;  // errFILE
    case Reject::kWrongHardware:
      return 0x01;  // errTARGET
    case Reject::kOversize:
      return 0x08;  // errADDRESS
    case Reject::kDowngrade:
      return 0x02;  // errFILE
    case Reject::kTruncated:
      return 0x09;  // errNOTDONE
    case Reject::kTrailingData:
      return 0x08;  // errADDRESS
    case Reject::kPayloadHash:
      return 0x07;  // errVERIFY
    case Reject::kUnsigned:
      return 0x02;  // errFILE
    case Reject::kUnknownKey:
      return 0x02;  // errFILE
    case Reject::kBadSignature:
      return 0x02;  // errFILE
  }
  return 0x0E;  // errUNKNOWN
}

Verdict Verdict::Fail(Reject r, const std::string& details) {
  Verdict v;
  v.reason = r;
  v.message = RejectToken(r);
  v.message.append(": ").append(details);
  return v;
}

Verdict ParseHeader(std::span<const uint8_t> b, ImageHeader* out) {
  if (b.size() < kHeaderBytes) {
    return Verdict::Fail(Reject::kTooShort,
                         std::to_string(b.size()) + " bytes, a header needs 128");
  }
  if (!std::equal(kImageMagic.begin(), kImageMagic.end(), b.begin())) {
    return Verdict::Fail(Reject::kBadMagic, "not a d3dscan firmware image (no D3DFWIMG magic)");
  }
  ImageHeader h;
  h.format_version = GetLe16(&b[8]);
  if (h.format_version != kImageFormatVersion) {
    return Verdict::Fail(
        Reject::kUnsupportedFormat,
        "format version " + std::to_string(h.format_version) + ", this probe reads 1");
  }
  if (GetLe16(&b[10]) != kHeaderBytes || !AllZero(&b[22], 2) || !AllZero(&b[28], 4) ||
      !AllZero(&b[80], 48)) {
    return Verdict::Fail(Reject::kBadHeader,
                         "header size field or reserved bytes are not as format 1 defines");
  }
  h.hw_id = GetLe32(&b[12]);
  h.version = SemVer{GetLe16(&b[16]), GetLe16(&b[18]), GetLe16(&b[20])};
  h.security_counter = GetLe32(&b[24]);
  h.payload_size = GetLe64(&b[32]);
  std::copy(b.begin() + 40, b.begin() + 72, h.payload_sha256.begin());
  std::copy(b.begin() + 72, b.begin() + 80, h.key_id.begin());
  if (out) *out = h;
  return {};
}

Verdict CheckPolicy(const ImageHeader& h, const ImagePolicy& p) {
  if (p.check_hw_id && h.hw_id != p.hw_id) {
    return Verdict::Fail(Reject::kWrongHardware, "image is for hardware " + HwHex(h.hw_id) +
                                                     ", this probe is " + HwHex(p.hw_id));
  }
  if (h.ImageSize() > p.max_image_bytes) {
    return Verdict::Fail(Reject::kOversize, "image needs " + std::to_string(h.ImageSize()) +
                                                " bytes, the slot holds " +
                                                std::to_string(p.max_image_bytes));
  }
  if (h.security_counter < p.min_security_counter) {
    return Verdict::Fail(Reject::kDowngrade, "security counter " +
                                                 std::to_string(h.security_counter) +
                                                 " is below the probe's floor " +
                                                 std::to_string(p.min_security_counter));
  }
  return {};
}

Verdict VerifyImage(const ImageReader& read, uint64_t available, const PublicKey& trusted_key,
                    const ImagePolicy& policy, ImageHeader* header_out) {
  EnsureSodium();
  std::array<uint8_t, kHeaderBytes> hb{};
  const size_t head = static_cast<size_t>(std::min<uint64_t>(available, kHeaderBytes));
  if (head > 0 && !read(0, std::span<uint8_t>(hb.data(), head))) {
    return Verdict::Fail(Reject::kTruncated, "could not read the header");
  }
  ImageHeader h;
  Verdict v = ParseHeader(std::span<const uint8_t>(hb.data(), head), &h);
  if (!v.ok()) return v;
  if (header_out) *header_out = h;
  v = CheckPolicy(h, policy);
  if (!v.ok()) return v;
  const uint64_t total = h.ImageSize();
  if (available < total) {
    return Verdict::Fail(Reject::kTruncated,
                         std::to_string(available) + " of " + std::to_string(total) + " bytes");
  }
  if (available > total) {
    return Verdict::Fail(Reject::kTrailingData, std::to_string(available - total) +
                                                    " bytes beyond the " + std::to_string(total) +
                                                    " the header announces");
  }
  crypto_hash_sha256_state sha;
  crypto_hash_sha256_init(&sha);
  crypto_sign_state sig_state;
  crypto_sign_init(&sig_state);
  crypto_sign_update(&sig_state, hb.data(), hb.size());
  std::vector<uint8_t> chunk(kChunkBytes);
  for (uint64_t off = 0; off < h.payload_size;) {
    const size_t n = static_cast<size_t>(std::min<uint64_t>(kChunkBytes, h.payload_size - off));
    if (!read(kHeaderBytes + off, std::span<uint8_t>(chunk.data(), n))) {
      return Verdict::Fail(Reject::kTruncated,
                           "could not read the payload at " + std::to_string(off));
    }
    crypto_hash_sha256_update(&sha, chunk.data(), n);
    crypto_sign_update(&sig_state, chunk.data(), n);
    off += n;
  }
  Sha256 digest;
  crypto_hash_sha256_final(&sha, digest.data());
  if (digest != h.payload_sha256) {
    return Verdict::Fail(Reject::kPayloadHash, "payload SHA-256 " +
                                                   Hex(std::span(digest).first(8)) +
                                                   "… differs from the header's " +
                                                   Hex(std::span(h.payload_sha256).first(8)) + "…");
  }
  std::array<uint8_t, kSignatureBytes> sig{};
  if (!read(kHeaderBytes + h.payload_size, sig)) {
    return Verdict::Fail(Reject::kTruncated, "could not read the signature");
  }
  if (AllZero(sig.data(), sig.size()))
    return Verdict::Fail(Reject::kUnsigned, "the image carries no signature");
  const KeyId trusted_id = KeyIdOf(trusted_key);
  if (h.key_id != trusted_id) {
    return Verdict::Fail(Reject::kUnknownKey, "signed with key " + Hex(h.key_id) +
                                                  ", the probe trusts " + Hex(trusted_id));
  }
  if (crypto_sign_final_verify(&sig_state, sig.data(), trusted_key.data()) != 0) {
    return Verdict::Fail(Reject::kBadSignature,
                         "Ed25519 signature does not verify: image modified");
  }
  return {};
}

Verdict VerifyImageBytes(std::span<const uint8_t> image, const PublicKey& trusted_key,
                         const ImagePolicy& policy, ImageHeader* header_out) {
  auto read = [image](uint64_t off, std::span<uint8_t> out) {
    if (off > image.size() || out.size() > image.size() - off) return false;
    std::memcpy(out.data(), image.data() + off, out.size());
    return true;
  };
  return VerifyImage(read, image.size(), trusted_key, policy, header_out);
}

std::vector<uint8_t> BuildImage(ImageHeader h, std::span<const uint8_t> payload,
                                const SecretKey* sk) {
  EnsureSodium();
  h.format_version = kImageFormatVersion;
  h.payload_size = payload.size();
  crypto_hash_sha256(h.payload_sha256.data(), payload.data(), payload.size());
  h.key_id = {};
  if (sk) {
    PublicKey pk;
    std::copy(sk->begin() + 32, sk->end(), pk.begin());
    h.key_id = KeyIdOf(pk);
  }
  const auto hb = h.Serialize();
  std::vector<uint8_t> image(kImageOverheadBytes + payload.size());
  std::memcpy(image.data(), hb.data(), hb.size());
  if (!payload.empty()) std::memcpy(image.data() + kHeaderBytes, payload.data(), payload.size());
  uint8_t* sig = image.data() + kHeaderBytes + payload.size();  // zero: unsigned until signed
  if (sk) {
    crypto_sign_state st;
    crypto_sign_init(&st);
    crypto_sign_update(&st, hb.data(), hb.size());
    crypto_sign_update(&st, payload.data(), payload.size());
    crypto_sign_final_create(&st, sig, nullptr, sk->data());
  }
  return image;
}

KeyId KeyIdOf(const PublicKey& pk) {
  EnsureSodium();
  Sha256 d;
  crypto_hash_sha256(d.data(), pk.data(), pk.size());
  KeyId id;
  std::copy(d.begin(), d.begin() + kKeyIdBytes, id.begin());
  return id;
}

std::string Hex(std::span<const uint8_t> bytes) {
  static const char* digits = "0123456789abcdef";
  std::string s;
  s.reserve(bytes.size() * 2);
  for (uint8_t b : bytes) {
    s.push_back(digits[b >> 4]);
    s.push_back(digits[b & 15]);
  }
  return s;
}

void GenerateKeyPair(PublicKey* pk, SecretKey* sk) {
  EnsureSodium();
  crypto_sign_keypair(pk->data(), sk->data());
}

void KeyPairFromSeed(std::span<const uint8_t, 32> seed, PublicKey* pk, SecretKey* sk) {
  EnsureSodium();
  crypto_sign_seed_keypair(pk->data(), sk->data(), seed.data());
}

namespace {

constexpr const char* kSecretKind = "d3dscan ed25519 secret key v1";
constexpr const char* kPublicKind = "d3dscan ed25519 public key v1";

Status SaveKey(const std::string& path, const char* kind, std::span<const uint8_t> key,
               bool secret) {
  // Created with its final mode, so a secret key is never readable by others, not even briefly.
  const int fd =
      ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, secret ? 0600 : 0644);
  if (fd < 0) return IoError("cannot write " + path);
  std::string text = kind;
  text.append("\n").append(Hex(key)).append("\n");
  const bool ok = ::write(fd, text.data(), text.size()) == static_cast<ssize_t>(text.size());
  const bool closed = ::close(fd) == 0;
  if (!ok || !closed) return IoError("cannot write " + path);
  if (secret && ::chmod(path.c_str(), 0600) != 0) return IoError("cannot set mode 0600 on " + path);
  return Status::Ok();
}

Status LoadKey(const std::string& path, const char* kind, std::span<uint8_t> key) {
  std::ifstream f(path);
  if (!f) return NotFound("cannot open key file " + path);
  std::string first, hex;
  std::getline(f, first);
  std::getline(f, hex);
  if (first != kind) return ParseError(path + ": not a " + std::string(kind) + " file");
  if (hex.size() != key.size() * 2) return ParseError(path + ": key has the wrong length");
  EnsureSodium();
  size_t got = 0;
  if (sodium_hex2bin(key.data(), key.size(), hex.data(), hex.size(), nullptr, &got, nullptr) != 0 ||
      got != key.size()) {
    return ParseError(path + ": key is not hex");
  }
  return Status::Ok();
}

}  // namespace

Status SaveSecretKey(const std::string& path, const SecretKey& sk) {
  return SaveKey(path, kSecretKind, sk, true);
}
Status SavePublicKey(const std::string& path, const PublicKey& pk) {
  return SaveKey(path, kPublicKind, pk, false);
}
Status LoadSecretKey(const std::string& path, SecretKey* sk) {
  return LoadKey(path, kSecretKind, *sk);
}
Status LoadPublicKey(const std::string& path, PublicKey* pk) {
  return LoadKey(path, kPublicKind, *pk);
}

}  // namespace d3d::fw
