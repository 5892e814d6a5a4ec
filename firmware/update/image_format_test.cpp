#include "firmware/update/image_format.h"

#include <gtest/gtest.h>
#include <sys/stat.h>

#include <filesystem>

#include "firmware/update/test_images.h"

namespace d3d::fw {
namespace {

using testing::MakeImage;
using testing::MakeTestKey;

ImagePolicy ProbePolicy() {
  ImagePolicy p;
  p.check_hw_id = true;
  p.hw_id = 0x0001;
  p.min_security_counter = 1;
  p.max_image_bytes = 1 << 20;
  return p;
}

TEST(ImageFormat, SignedImageVerifiesAndRoundTripsTheHeader) {
  const auto key = MakeTestKey(1);
  const auto img = MakeImage(&key, {1, 2, 3}, 5, 0x0001, 10000);
  ASSERT_EQ(img.size(), 10000 + kImageOverheadBytes);
  ImageHeader h;
  const Verdict v = VerifyImageBytes(img, key.pk, ProbePolicy(), &h);
  EXPECT_TRUE(v.ok()) << v.message;
  EXPECT_EQ(h.version, (SemVer{1, 2, 3}));
  EXPECT_EQ(h.security_counter, 5u);
  EXPECT_EQ(h.hw_id, 0x0001u);
  EXPECT_EQ(h.payload_size, 10000u);
  EXPECT_EQ(h.key_id, KeyIdOf(key.pk));
  ImageHeader again;
  ASSERT_TRUE(ParseHeader(h.Serialize(), &again).ok());
  EXPECT_EQ(again.Serialize(), h.Serialize());
  EXPECT_TRUE(std::equal(img.begin(), img.begin() + kHeaderBytes, h.Serialize().begin()));
}

TEST(ImageFormat, EmptyPayloadIsValid) {
  const auto key = MakeTestKey(1);
  EXPECT_TRUE(VerifyImageBytes(MakeImage(&key, {1, 0, 0}, 1, 1, 0), key.pk, ProbePolicy()).ok());
}

struct RejectCase {
  const char* name;
  Reject expected;
};

TEST(ImageFormat, EachRefusalHasItsExactReason) {
  const auto key = MakeTestKey(1), other = MakeTestKey(2);
  const auto good = MakeImage(&key, {1, 1, 0}, 2, 0x0001, 5000);
  auto check = [&](std::vector<uint8_t> img, Reject want, ImagePolicy pol = ProbePolicy()) {
    const Verdict v = VerifyImageBytes(img, key.pk, pol);
    EXPECT_EQ(v.reason, want) << v.message;
    EXPECT_EQ(v.message.rfind(RejectToken(want), 0), 0u) << v.message;
  };
  check(std::vector<uint8_t>(good.begin(), good.begin() + 100), Reject::kTooShort);
  auto bad_magic = good;
  bad_magic[0] = 'X';
  check(bad_magic, Reject::kBadMagic);
  auto fmt = good;
  fmt[8] = 2;
  check(fmt, Reject::kUnsupportedFormat);
  auto reserved = good;
  reserved[100] = 1;
  check(reserved, Reject::kBadHeader);
  check(MakeImage(&key, {1, 1, 0}, 2, 0x0002, 5000), Reject::kWrongHardware);
  ImagePolicy small = ProbePolicy();
  small.max_image_bytes = 4096;
  check(good, Reject::kOversize, small);
  check(MakeImage(&key, {0, 9, 0}, 0, 0x0001, 5000), Reject::kDowngrade);
  check(std::vector<uint8_t>(good.begin(), good.end() - 1), Reject::kTruncated);
  auto trailing = good;
  trailing.push_back(0);
  check(trailing, Reject::kTrailingData);
  auto payload = good;
  payload[kHeaderBytes + 17] ^= 0x04;
  check(payload, Reject::kPayloadHash);
  check(MakeImage(nullptr, {1, 1, 0}, 2, 0x0001, 5000), Reject::kUnsigned);
  check(MakeImage(&other, {1, 1, 0}, 2, 0x0001, 5000), Reject::kUnknownKey);
  auto version = good;
  version[18] ^= 1;  // minor version: hash and key id fine, signature not
  check(version, Reject::kBadSignature);
  auto sig = good;
  sig[sig.size() - 3] ^= 0x80;
  check(sig, Reject::kBadSignature);
}

TEST(ImageFormat, EveryFlippedBitOfHeaderAndSignatureAndSampledPayloadBitsAreRefused) {
  const auto key = MakeTestKey(1);
  const auto good = MakeImage(&key, {1, 1, 0}, 2, 0x0001, 3000);
  std::vector<size_t> bytes;
  for (size_t i = 0; i < kHeaderBytes; ++i) bytes.push_back(i);
  for (size_t i = good.size() - kSignatureBytes; i < good.size(); ++i) bytes.push_back(i);
  for (size_t i = kHeaderBytes; i < good.size() - kSignatureBytes; i += 97) bytes.push_back(i);
  ImagePolicy pol = ProbePolicy();
  int refused = 0;
  for (size_t i : bytes) {
    for (int bit = 0; bit < 8; ++bit) {
      auto img = good;
      img[i] ^= static_cast<uint8_t>(1 << bit);
      const Verdict v = VerifyImageBytes(img, key.pk, pol);
      ASSERT_FALSE(v.ok()) << "flip of byte " << i << " bit " << bit << " was accepted";
      ++refused;
    }
  }
  EXPECT_EQ(refused, static_cast<int>(bytes.size()) * 8);
}

TEST(ImageFormat, DfuStatusMapping) {
  EXPECT_EQ(DfuStatusFor(Reject::kWrongHardware), 0x01);  // errTARGET
  EXPECT_EQ(DfuStatusFor(Reject::kBadSignature), 0x02);   // errFILE
  EXPECT_EQ(DfuStatusFor(Reject::kPayloadHash), 0x07);    // errVERIFY
  EXPECT_EQ(DfuStatusFor(Reject::kOversize), 0x08);       // errADDRESS
  EXPECT_EQ(DfuStatusFor(Reject::kTruncated), 0x09);      // errNOTDONE
}

TEST(ImageFormat, SemVerParsing) {
  SemVer v;
  EXPECT_TRUE(SemVer::Parse("1.10.3", &v));
  EXPECT_EQ(v, (SemVer{1, 10, 3}));
  EXPECT_EQ(v.ToString(), "1.10.3");
  EXPECT_FALSE(SemVer::Parse("1.2", &v));
  EXPECT_FALSE(SemVer::Parse("1.2.3.4", &v));
  EXPECT_FALSE(SemVer::Parse("1..3", &v));
  EXPECT_FALSE(SemVer::Parse("1.2.70000", &v));
  EXPECT_FALSE(SemVer::Parse("a.b.c", &v));
  EXPECT_LT((SemVer{1, 0, 9}), (SemVer{1, 1, 0}));
}

TEST(ImageFormat, KeyFilesRoundTripAndTheSecretKeyIsPrivate) {
  const auto dir =
      std::filesystem::temp_directory_path() / ("d3d_keys_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  const auto k = MakeTestKey(3);
  const PublicKey& pk = k.pk;
  const SecretKey& sk = k.sk;
  ASSERT_TRUE(SaveSecretKey((dir / "signing.key").string(), sk).ok());
  ASSERT_TRUE(SavePublicKey((dir / "signing.pub").string(), pk).ok());
  struct stat st {};
  ASSERT_EQ(::stat((dir / "signing.key").c_str(), &st), 0);
  EXPECT_EQ(st.st_mode & 0777, 0600u);
  PublicKey pk2;
  SecretKey sk2;
  ASSERT_TRUE(LoadSecretKey((dir / "signing.key").string(), &sk2).ok());
  ASSERT_TRUE(LoadPublicKey((dir / "signing.pub").string(), &pk2).ok());
  EXPECT_EQ(pk, pk2);
  EXPECT_EQ(sk, sk2);
  EXPECT_FALSE(LoadPublicKey((dir / "signing.key").string(), &pk2).ok());  // wrong kind
  EXPECT_EQ(LoadPublicKey((dir / "none.pub").string(), &pk2).code(), StatusCode::kNotFound);
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace d3d::fw
