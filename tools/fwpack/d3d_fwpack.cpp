// d3d-fwpack: key generation, signing and verification of d3dscan firmware images
// (format: firmware/update/image_format.h; key handling: firmware/update/README.md).
#include <cstdio>
#include <filesystem>
#include <fstream>

#include "common/options/option_registry.h"
#include "firmware/update/image_format.h"

using namespace d3d;
using namespace d3d::fw;

namespace {

bool ReadFile(const std::string& path, std::vector<uint8_t>* out) {
  std::ifstream f(path, std::ios::binary);
  if (!f) return false;
  out->assign(std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>());
  return true;
}

bool WriteFile(const std::string& path, std::span<const uint8_t> data) {
  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  f.write(reinterpret_cast<const char*>(data.data()), static_cast<std::streamsize>(data.size()));
  return static_cast<bool>(f);
}

std::string Mib(uint64_t bytes) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%.2f MiB", static_cast<double>(bytes) / (1 << 20));
  return buf;
}

int Fail(const std::string& msg, int code = 2) {
  std::fprintf(stderr, "d3d-fwpack: %s\n", msg.c_str());
  return code;
}

struct FwpackOptions {
  bool keygen = false, verify = false, is_unsigned = false, force = false;
  std::string out, key, version, hw, in, pubkey, image;
  uint32_t counter = 0, min_counter = 0;
  uint64_t max_size = 0;
};

void DeclareOptions(OptionRegistry* r, FwpackOptions* o) {
  r->Flag("--keygen", &o->keygen, "generate an Ed25519 signing key pair into --out DIR");
  r->Flag("--verify", &o->verify, "verify IMAGE with --pubkey as a probe would");
  r->Add("--out", &o->out, "key directory (--keygen) or image file to write");
  r->Add("--key", &o->key, "signing.key to sign with");
  r->Flag("--unsigned", &o->is_unsigned, "write an unsigned image (tests: every probe refuses it)");
  r->Add("--version", &o->version, "firmware semantic version MAJOR.MINOR.PATCH");
  r->Add("--hw", &o->hw, "hardware compatibility id (e.g. 0x0001)");
  r->Add("--counter", &o->counter,
         "security counter (anti-rollback); raise it to retire older images");
  r->Add("--in", &o->in, "payload file (the firmware itself)");
  r->Add("--pubkey", &o->pubkey, "signing.pub a probe trusts (--verify)");
  r->Add("--min-counter", &o->min_counter, "the probe's anti-rollback floor (--verify)");
  r->Add("--max-size", &o->max_size,
         "the probe's slot capacity in bytes (--verify; default: no limit)");
  r->Flag("--force", &o->force, "overwrite existing key files (--keygen)");
  r->Add("image", &o->image, "image to verify (--verify)");
}

// --keygen: a new key pair in --out (never over an existing one unless --force).
int Keygen(const FwpackOptions& o) {
  if (o.out.empty()) return Fail("--keygen needs --out DIR");
  std::filesystem::create_directories(o.out);
  const std::string sk_path = o.out + "/signing.key", pk_path = o.out + "/signing.pub";
  if (!o.force && (std::filesystem::exists(sk_path) || std::filesystem::exists(pk_path))) {
    return Fail(sk_path + " exists; refusing to overwrite a signing key (--force to replace it)");
  }
  PublicKey pk;
  SecretKey sk;
  GenerateKeyPair(&pk, &sk);
  if (Status s = SaveSecretKey(sk_path, sk); !s.ok()) return Fail(s.ToString());
  if (Status s = SavePublicKey(pk_path, pk); !s.ok()) return Fail(s.ToString());
  std::printf("secret key  %s (mode 0600: keep it offline, never on a probe)\n", sk_path.c_str());
  std::printf("public key  %s (install on every probe)\n", pk_path.c_str());
  std::printf("key id      %s\n", Hex(KeyIdOf(pk)).c_str());
  return 0;
}

// --verify: the image's header and the verdict a probe with this key and policy would give
// (0 accepted, 1 refused).
int Verify(const FwpackOptions& o) {
  if (o.pubkey.empty() || o.image.empty()) return Fail("--verify needs --pubkey PUB and IMAGE");
  PublicKey pk;
  if (Status s = LoadPublicKey(o.pubkey, &pk); !s.ok()) return Fail(s.ToString());
  std::vector<uint8_t> bytes;
  if (!ReadFile(o.image, &bytes)) return Fail("cannot read " + o.image);
  ImagePolicy policy;
  if (!o.hw.empty()) {
    policy.check_hw_id = true;
    policy.hw_id = static_cast<uint32_t>(std::stoul(o.hw, nullptr, 0));
  }
  policy.min_security_counter = o.min_counter;
  if (o.max_size > 0) policy.max_image_bytes = o.max_size;
  ImageHeader h;
  const Verdict v = VerifyImageBytes(bytes, pk, policy, &h);
  std::printf("image      %s (%zu bytes)\n", o.image.c_str(), bytes.size());
  if (ParseHeader(bytes, nullptr).ok()) {
    char hwbuf[16];
    std::snprintf(hwbuf, sizeof(hwbuf), "0x%04x", h.hw_id);
    std::printf("version    %s\n", h.version.ToString().c_str());
    std::printf("hardware   %s\n", hwbuf);
    std::printf("counter    %u\n", h.security_counter);
    std::printf("payload    %llu bytes (%s), SHA-256 %s\n",
                static_cast<unsigned long long>(h.payload_size), Mib(h.payload_size).c_str(),
                Hex(h.payload_sha256).c_str());
    std::printf("key id     %s (trusted: %s)\n", Hex(h.key_id).c_str(), Hex(KeyIdOf(pk)).c_str());
  }
  if (!v.ok()) {
    std::printf("verdict    REFUSED: %s\n", v.message.c_str());
    return 1;
  }
  std::printf("verdict    OK: signature, hash and size verify%s%s\n",
              policy.check_hw_id ? ", hardware id matches" : "",
              o.min_counter > 0 ? ", counter ≥ floor" : "");
  return 0;
}

// Packing: the payload with its header, signed with --key (or --unsigned), written to --out.
int Pack(const FwpackOptions& o) {
  if (o.in.empty() || o.out.empty() || o.version.empty() || o.hw.empty() ||
      (o.key.empty() && !o.is_unsigned)) {
    return Fail(
        "packing needs --key KEY (or --unsigned) --version V --hw ID --counter N --in PAYLOAD "
        "--out IMAGE");
  }
  ImageHeader h;
  if (!SemVer::Parse(o.version, &h.version))
    return Fail("--version must be MAJOR.MINOR.PATCH, got " + o.version);
  h.hw_id = static_cast<uint32_t>(std::stoul(o.hw, nullptr, 0));
  h.security_counter = o.counter;
  std::vector<uint8_t> payload;
  if (!ReadFile(o.in, &payload)) return Fail("cannot read " + o.in);
  SecretKey sk;
  if (!o.is_unsigned) {
    if (Status s = LoadSecretKey(o.key, &sk); !s.ok()) return Fail(s.ToString());
  }
  const auto img = BuildImage(h, payload, o.is_unsigned ? nullptr : &sk);
  if (!WriteFile(o.out, img)) return Fail("cannot write " + o.out);
  ImageHeader written;
  (void)ParseHeader(img, &written);
  std::printf("wrote %s: firmware %s for hardware 0x%04x, counter %u, %s payload, %s, key id %s\n",
              o.out.c_str(), h.version.ToString().c_str(), h.hw_id, h.security_counter,
              Mib(payload.size()).c_str(), o.is_unsigned ? "UNSIGNED" : "signed (Ed25519ph)",
              Hex(written.key_id).c_str());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  // The registry has no help footer: the modes follow the description.
  OptionRegistry options(
      "d3d-fwpack: make signing keys, sign firmware images, verify them as a probe would\n"
      "Modes:\n"
      "  d3d-fwpack --keygen --out DIR                 writes DIR/signing.key (0600) and "
      "DIR/signing.pub\n"
      "  d3d-fwpack --key KEY --version V --hw ID --counter N --in PAYLOAD --out IMAGE\n"
      "  d3d-fwpack --verify --pubkey PUB [--hw ID] [--min-counter N] [--max-size BYTES] IMAGE\n"
      "--verify exits 0 when a probe would accept the image, 1 naming the reason when it would "
      "refuse it,\n"
      "2 on usage or I/O errors.");
  FwpackOptions o;
  DeclareOptions(&options, &o);
  if (int code = 0; !options.Parse(argc, argv, &code)) return code;
  try {
    if (o.keygen) return Keygen(o);
    if (o.verify) return Verify(o);
    return Pack(o);
  } catch (const std::exception& e) {
    return Fail(e.what());
  }
}
