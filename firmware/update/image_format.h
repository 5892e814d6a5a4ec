// The signed firmware image of the d3dscan probe: a 128-byte header, the payload, and a 64-byte
// Ed25519ph signature over header ‖ payload.
//
// Header (little-endian, 128 bytes):
//   0   char[8]  magic "D3DFWIMG"
//   8   u16      format version (1)
//   10  u16      header size (128)
//   12  u32      hardware compatibility id (the probe refuses any other)
//   16  u16×3    firmware semantic version major.minor.patch, then u16 reserved (0)
//   24  u32      security counter (anti-rollback: the probe refuses counters below its floor)
//   28  u32      reserved (0)
//   32  u64      payload size in bytes
//   40  u8[32]   SHA-256 of the payload
//   72  u8[8]    key id: the first 8 bytes of SHA-256(public key) the image was signed with
//   80  u8[48]   reserved (0)
// Signature: Ed25519ph (RFC 8032 §5.1, pre-hashed with SHA-512; libsodium crypto_sign_init /
// update / final_create / final_verify) over the 128 header bytes followed by the payload. The
// pre-hashed variant lets the probe verify an image streamed from flash in one pass with O(1) RAM.
// An unsigned image carries 64 zero bytes in place of the signature.
//
// Every check a probe makes is here, in a fixed order, so that `d3d-fwpack --verify`, the probe's
// update agent and the boot verification give the same reason for the same bytes.
#pragma once

#include <array>
#include <cstdint>
#include <functional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "common/core/status.h"

namespace d3d::fw {

inline constexpr std::array<uint8_t, 8> kImageMagic = {'D', '3', 'D', 'F', 'W', 'I', 'M', 'G'};
inline constexpr uint16_t kImageFormatVersion = 1;
inline constexpr size_t kHeaderBytes = 128;
inline constexpr size_t kSignatureBytes = 64;
inline constexpr size_t kKeyIdBytes = 8;
inline constexpr size_t kImageOverheadBytes = kHeaderBytes + kSignatureBytes;

using PublicKey = std::array<uint8_t, 32>;  // Ed25519 public key
using SecretKey = std::array<uint8_t, 64>;  // libsodium Ed25519 secret key (seed ‖ public key)
using KeyId = std::array<uint8_t, kKeyIdBytes>;
using Sha256 = std::array<uint8_t, 32>;

struct SemVer {
  uint16_t major = 0, minor = 0, patch = 0;
  std::string ToString() const;
  // Parses "1.2.3" (each part 0..65535). False otherwise.
  static bool Parse(std::string_view text, SemVer* out);
  auto operator<=>(const SemVer&) const = default;
};

struct ImageHeader {
  uint16_t format_version = kImageFormatVersion;
  uint32_t hw_id = 0;
  SemVer version;
  uint32_t security_counter = 0;
  uint64_t payload_size = 0;
  Sha256 payload_sha256{};
  KeyId key_id{};

  std::array<uint8_t, kHeaderBytes> Serialize() const;
  // Total image size (header + payload + signature); saturates at UINT64_MAX.
  uint64_t ImageSize() const;
};

// Why a probe refuses an image. Order = order of the checks.
enum class Reject : uint8_t {
  kNone = 0,
  kTooShort,           // fewer than 128 bytes: no complete header
  kBadMagic,           // not a d3dscan firmware image
  kUnsupportedFormat,  // format version this probe does not know
  kBadHeader,          // header size field or reserved bytes wrong
  kWrongHardware,      // hardware compatibility id differs from the probe's
  kOversize,           // image larger than the probe's slot
  kDowngrade,          // security counter below the probe's anti-rollback floor
  kTruncated,          // fewer bytes than the header announces
  kTrailingData,       // more bytes than the header announces
  kPayloadHash,        // payload SHA-256 differs from the header's
  kUnsigned,           // the signature block is all zero
  kUnknownKey,         // signed with a key this probe does not trust (key id differs)
  kBadSignature,       // key id matches but the signature does not verify (modified image)
};
// Stable token naming the reason ("bad-signature"); used in messages and by tests.
const char* RejectToken(Reject r);
// The USB DFU 1.1 bStatus the probe reports for this reason (dfu_protocol.h).
uint8_t DfuStatusFor(Reject r);

struct Verdict {
  Reject reason = Reject::kNone;
  std::string message;  // "<token>: <details>", empty when ok
  bool ok() const { return reason == Reject::kNone; }
  static Verdict Fail(Reject r, const std::string& details);
};

// What the probe accepts. Defaults accept any hardware id / counter / size (for inspection).
struct ImagePolicy {
  bool check_hw_id = false;
  uint32_t hw_id = 0;
  uint32_t min_security_counter = 0;
  uint64_t max_image_bytes = UINT64_MAX;  // the slot capacity
};

// Structural parse of the first 128 bytes (checks up to kBadHeader). `bytes` may be longer.
Verdict ParseHeader(std::span<const uint8_t> bytes, ImageHeader* out);
// Policy checks on a parsed header: hardware id, size, security counter (in that order).
Verdict CheckPolicy(const ImageHeader& h, const ImagePolicy& policy);

// Reads `out.size()` bytes of the image at `offset`; returns false on an I/O failure.
using ImageReader = std::function<bool(uint64_t offset, std::span<uint8_t> out)>;

// Full verification of an image of `available_bytes` bytes accessible through `read` (a file, a
// flash slot): header, policy, length, payload hash and signature, in one streaming pass.
// `header_out` (optional) receives the parsed header when it parses.
Verdict VerifyImage(const ImageReader& read, uint64_t available_bytes, const PublicKey& trusted_key,
                    const ImagePolicy& policy, ImageHeader* header_out = nullptr);
// Convenience for an image in memory.
Verdict VerifyImageBytes(std::span<const uint8_t> image, const PublicKey& trusted_key,
                         const ImagePolicy& policy, ImageHeader* header_out = nullptr);

// Builds a signed image: fills payload_size, payload_sha256 and key_id of `header`, signs with
// `secret_key` (Ed25519ph). With `secret_key == nullptr` the image is unsigned (zero key id and
// signature). Throws std::invalid_argument if libsodium cannot be initialised.
std::vector<uint8_t> BuildImage(ImageHeader header, std::span<const uint8_t> payload,
                                const SecretKey* secret_key);

KeyId KeyIdOf(const PublicKey& pk);
std::string Hex(std::span<const uint8_t> bytes);

// Key generation and key files. Files are text: a first line naming the kind
// ("d3dscan ed25519 secret key v1" / "d3dscan ed25519 public key v1") and a hex line.
// The secret key file is written with mode 0600.
void GenerateKeyPair(PublicKey* pk, SecretKey* sk);  // OS randomness
void KeyPairFromSeed(std::span<const uint8_t, 32> seed, PublicKey* pk, SecretKey* sk);  // tests
Status SaveSecretKey(const std::string& path, const SecretKey& sk);
Status SavePublicKey(const std::string& path, const PublicKey& pk);
Status LoadSecretKey(const std::string& path, SecretKey* sk);
Status LoadPublicKey(const std::string& path, PublicKey* pk);

// Initialises libsodium once (thread-safe); throws std::runtime_error if it cannot.
void EnsureSodium();

}  // namespace d3d::fw
