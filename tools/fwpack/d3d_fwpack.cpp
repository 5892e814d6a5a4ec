// d3d-fwpack: key generation, signing and verification of d3dscan firmware images
// (format: firmware/update/image_format.h; key handling: firmware/update/README.md).
#include <CLI/CLI.hpp>
#include <cstdio>
#include <filesystem>
#include <fstream>

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

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"d3d-fwpack: make signing keys, sign firmware images, verify them as a probe would"};
  app.footer(
      "Modes:\n"
      "  d3d-fwpack --keygen --out DIR                 writes DIR/signing.key (0600) and DIR/signing.pub\n"
      "  d3d-fwpack --key KEY --version V --hw ID --counter N --in PAYLOAD --out IMAGE\n"
      "  d3d-fwpack --verify --pubkey PUB [--hw ID] [--min-counter N] [--max-size BYTES] IMAGE\n"
      "--verify exits 0 when a probe would accept the image, 1 naming the reason when it would refuse it,\n"
      "2 on usage or I/O errors.");
  bool keygen = false, verify = false, is_unsigned = false, force = false;
  std::string out, key, version, hw, in, pubkey, image;
  uint32_t counter = 0, min_counter = 0;
  uint64_t max_size = 0;
  app.add_flag("--keygen", keygen, "generate an Ed25519 signing key pair into --out DIR");
  app.add_flag("--verify", verify, "verify IMAGE with --pubkey as a probe would");
  app.add_option("--out", out, "key directory (--keygen) or image file to write");
  app.add_option("--key", key, "signing.key to sign with");
  app.add_flag("--unsigned", is_unsigned, "write an unsigned image (tests: every probe refuses it)");
  app.add_option("--version", version, "firmware semantic version MAJOR.MINOR.PATCH");
  app.add_option("--hw", hw, "hardware compatibility id (e.g. 0x0001)");
  app.add_option("--counter", counter, "security counter (anti-rollback); raise it to retire older images");
  app.add_option("--in", in, "payload file (the firmware itself)");
  app.add_option("--pubkey", pubkey, "signing.pub a probe trusts (--verify)");
  app.add_option("--min-counter", min_counter, "the probe's anti-rollback floor (--verify)");
  app.add_option("--max-size", max_size, "the probe's slot capacity in bytes (--verify; default: no limit)");
  app.add_flag("--force", force, "overwrite existing key files (--keygen)");
  app.add_option("image", image, "image to verify (--verify)");
  CLI11_PARSE(app, argc, argv);

  try {
    if (keygen) {
      if (out.empty()) return Fail("--keygen needs --out DIR");
      std::filesystem::create_directories(out);
      const std::string sk_path = out + "/signing.key", pk_path = out + "/signing.pub";
      if (!force && (std::filesystem::exists(sk_path) || std::filesystem::exists(pk_path))) {
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

    if (verify) {
      if (pubkey.empty() || image.empty()) return Fail("--verify needs --pubkey PUB and IMAGE");
      PublicKey pk;
      if (Status s = LoadPublicKey(pubkey, &pk); !s.ok()) return Fail(s.ToString());
      std::vector<uint8_t> bytes;
      if (!ReadFile(image, &bytes)) return Fail("cannot read " + image);
      ImagePolicy policy;
      if (!hw.empty()) {
        policy.check_hw_id = true;
        policy.hw_id = static_cast<uint32_t>(std::stoul(hw, nullptr, 0));
      }
      policy.min_security_counter = min_counter;
      if (max_size > 0) policy.max_image_bytes = max_size;
      ImageHeader h;
      const Verdict v = VerifyImageBytes(bytes, pk, policy, &h);
      std::printf("image      %s (%zu bytes)\n", image.c_str(), bytes.size());
      if (ParseHeader(bytes, nullptr).ok()) {
        char hwbuf[16];
        std::snprintf(hwbuf, sizeof(hwbuf), "0x%04x", h.hw_id);
        std::printf("version    %s\n", h.version.ToString().c_str());
        std::printf("hardware   %s\n", hwbuf);
        std::printf("counter    %u\n", h.security_counter);
        std::printf("payload    %llu bytes (%s), SHA-256 %s\n", static_cast<unsigned long long>(h.payload_size),
                    Mib(h.payload_size).c_str(), Hex(h.payload_sha256).c_str());
        std::printf("key id     %s (trusted: %s)\n", Hex(h.key_id).c_str(), Hex(KeyIdOf(pk)).c_str());
      }
      if (!v.ok()) {
        std::printf("verdict    REFUSED: %s\n", v.message.c_str());
        return 1;
      }
      std::printf("verdict    OK: signature, hash and size verify%s%s\n", policy.check_hw_id ? ", hardware id matches" : "",
                  min_counter > 0 ? ", counter ≥ floor" : "");
      return 0;
    }

    // Pack.
    if (in.empty() || out.empty() || version.empty() || hw.empty() || (key.empty() && !is_unsigned)) {
      return Fail("packing needs --key KEY (or --unsigned) --version V --hw ID --counter N --in PAYLOAD --out IMAGE");
    }
    ImageHeader h;
    if (!SemVer::Parse(version, &h.version)) return Fail("--version must be MAJOR.MINOR.PATCH, got " + version);
    h.hw_id = static_cast<uint32_t>(std::stoul(hw, nullptr, 0));
    h.security_counter = counter;
    std::vector<uint8_t> payload;
    if (!ReadFile(in, &payload)) return Fail("cannot read " + in);
    SecretKey sk;
    if (!is_unsigned) {
      if (Status s = LoadSecretKey(key, &sk); !s.ok()) return Fail(s.ToString());
    }
    const auto img = BuildImage(h, payload, is_unsigned ? nullptr : &sk);
    if (!WriteFile(out, img)) return Fail("cannot write " + out);
    ImageHeader written;
    (void)ParseHeader(img, &written);
    std::printf("wrote %s: firmware %s for hardware 0x%04x, counter %u, %s payload, %s, key id %s\n", out.c_str(),
                h.version.ToString().c_str(), h.hw_id, h.security_counter, Mib(payload.size()).c_str(),
                is_unsigned ? "UNSIGNED" : "signed (Ed25519ph)", Hex(written.key_id).c_str());
    return 0;
  } catch (const std::exception& e) {
    return Fail(e.what());
  }
}
