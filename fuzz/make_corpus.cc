// Writes the seed corpus of every fuzz target: `fuzz_make_corpus <repo root> <corpus dir>`.
//
// Binary seeds are made with the encoders the real senders use (frame headers, PLANET values
// and RMI messages, COROS datagrams), so every seed is a valid input that takes the decoders
// deep. Text seeds are the repository's own IDL files (bundled with the files they include)
// and policy files. Each target's directory is replaced whole, so the output depends only on
// this program and the repository: run it again after a protocol change, and commit the result.
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include <fmt/format.h>

#include "icars/coros/messages.h"
#include "icars/planet/event.h"
#include "icars/planet/frame.h"
#include "icars/planet/rmi_message.h"
#include "icars/planet/serializer.h"
#include "payload_types.h"

namespace {

namespace fs = std::filesystem;
namespace p = icars::planet;
namespace co = icars::coros;
using namespace icars_fuzz;
using Bytes = std::vector<std::byte>;

void write(const fs::path& path, std::span<const std::byte> bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
  if (!out) throw std::runtime_error("cannot write " + path.string());
}

void write_text(const fs::path& path, std::string_view text) {
  write(path, std::as_bytes(std::span(text.data(), text.size())));
}

std::string read_text(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error("cannot read " + path.string());
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

fs::path fresh_dir(const fs::path& dir) {
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

// --- frame_decoder_fuzz: byte streams as a receiver sees them ------------------------------

void append_frame(Bytes& out, p::FrameCode code, std::uint32_t msg_no, std::uint32_t frame_no,
                  bool final, std::span<const std::byte> payload) {
  p::FrameHeader h;
  h.code = code;
  h.msg_no = msg_no;
  h.frame_no = frame_no;
  h.final = final;
  h.length = static_cast<std::uint32_t>(p::kFrameHeaderSize + payload.size());
  const auto header = p::encode_header(h);
  out.insert(out.end(), header.begin(), header.end());
  out.insert(out.end(), payload.begin(), payload.end());
}

Bytes filled(std::size_t n, std::uint8_t seed) {
  Bytes b(n);
  for (std::size_t i = 0; i < n; ++i) b[i] = std::byte{static_cast<std::uint8_t>(seed + i * 7)};
  return b;
}

void make_frame_corpus(const fs::path& dir) {
  using p::FrameCode;
  const auto connect = [] {
    Bytes b;
    p::Writer(b).str("client-pun");
    return b;
  }();
  const auto connect_ack = [](std::uint8_t status, std::string_view text) {
    Bytes b;
    p::Writer w(b);
    w.u8(status);
    w.str(text);
    return b;
  };
  const auto data_ack = [](std::uint32_t msg_no, p::AckCode code) {
    Bytes b;
    p::Writer w(b);
    w.u32(msg_no);
    w.u32(static_cast<std::uint32_t>(code));
    return b;
  };

  Bytes handshake;
  append_frame(handshake, FrameCode::connect, 0, 0, true, connect);
  append_frame(handshake, FrameCode::heartbeat, 0, 0, true, {});
  write(dir / "handshake_heartbeat.bin", handshake);

  Bytes accepted;
  append_frame(accepted, FrameCode::connect_ack, 0, 0, true,
               connect_ack(p::kConnectAccept, "server-pun"));
  append_frame(accepted, FrameCode::heartbeat_ack, 0, 0, true, {});
  append_frame(accepted, FrameCode::data_ack, 0, 0, true, data_ack(7, p::AckCode::more));
  append_frame(accepted, FrameCode::data_ack, 0, 0, true, data_ack(8, p::AckCode::no_more));
  write(dir / "connect_ack_and_acks.bin", accepted);

  Bytes denied;
  append_frame(denied, FrameCode::connect_ack, 0, 0, true,
               connect_ack(p::kConnectDeny, "unsupported protocol version"));
  write(dir / "connect_denied.bin", denied);

  Bytes single;
  append_frame(single, FrameCode::data, 1, 0, true, filled(40, 1));
  append_frame(single, FrameCode::data, 2, 0, true, {});
  write(dir / "data_single_frames.bin", single);

  // Two multi-frame messages interleaved, as the I/O scheduler sends them.
  Bytes interleaved;
  append_frame(interleaved, FrameCode::data, 3, 0, false, filled(300, 3));
  append_frame(interleaved, FrameCode::data, 4, 0, false, filled(200, 4));
  append_frame(interleaved, FrameCode::data, 3, 1, false, filled(300, 5));
  append_frame(interleaved, FrameCode::data, 4, 1, true, filled(10, 6));
  append_frame(interleaved, FrameCode::data, 3, 2, true, filled(30, 7));
  write(dir / "data_interleaved.bin", interleaved);

  Bytes full;
  append_frame(full, FrameCode::data, 9, 0, false, filled(p::kMaxFramePayload, 9));
  append_frame(full, FrameCode::data, 9, 1, true, filled(16, 10));
  write(dir / "data_full_frame.bin", full);

  Bytes partial;  // a stream that ends inside a frame's payload
  append_frame(partial, FrameCode::data, 5, 0, true, filled(64, 11));
  partial.resize(partial.size() - 10);
  write(dir / "data_truncated.bin", partial);
}

// --- payload_fuzz: RMI messages and read sequences ------------------------------------------

Pose sample_pose(double at) {
  return Pose{at, -at, "map", {1, 2, 3}};
}
p::Event sample_event() {
  p::Event e("SoundEvent");
  e.set("direction", 1.25).set("level_db", std::int32_t{60}).set("room", std::string("bedroom"));
  e.set("pose", sample_pose(2)).set("tags", std::vector<std::string>{"a", "b"});
  return e;
}

template <class T>
T sample(Bare<T>) {
  if constexpr (std::is_same_v<T, bool>) {
    return true;
  } else if constexpr (std::is_same_v<T, std::uint8_t>) {
    return 0xAB;
  } else if constexpr (std::is_same_v<T, std::int16_t>) {
    return -1234;
  } else if constexpr (std::is_same_v<T, std::int32_t>) {
    return 123456;
  } else if constexpr (std::is_same_v<T, std::int64_t>) {
    return -9876543210;
  } else if constexpr (std::is_same_v<T, float>) {
    return 1.5F;
  } else if constexpr (std::is_same_v<T, double>) {
    return -2.75;
  } else if constexpr (std::is_same_v<T, std::string>) {
    return "living room";
  } else if constexpr (std::is_same_v<T, p::Binary>) {
    return p::Binary{filled(12, 42)};
  } else if constexpr (std::is_same_v<T, p::StreamRef>) {
    return p::StreamRef{7};
  } else if constexpr (std::is_same_v<T, p::ObjectRef>) {
    return p::ObjectRef{"server", "/home/tv", "home::TV"};
  } else if constexpr (std::is_same_v<T, p::Ref<Listener>>) {
    return p::Ref<Listener>(p::ObjectRef{"", "/listener", std::string(Listener::type_id)});
  } else if constexpr (std::is_same_v<T, std::vector<std::uint8_t>>) {
    return {1, 2, 3, 4};
  } else if constexpr (std::is_same_v<T, std::vector<std::int32_t>>) {
    return {-1, 0, 1};
  } else if constexpr (std::is_same_v<T, std::vector<std::string>>) {
    return {"one", "", "three"};
  } else if constexpr (std::is_same_v<T, std::vector<std::vector<double>>>) {
    return {{1.0, 2.0}, {}, {3.0}};
  } else if constexpr (std::is_same_v<T, std::vector<bool>>) {
    return {true, false, true};
  } else if constexpr (std::is_same_v<T, Color>) {
    return Color::blue;
  } else if constexpr (std::is_same_v<T, Pose>) {
    return sample_pose(1);
  } else if constexpr (std::is_same_v<T, Route>) {
    return Route{"patrol", Color::green, sample_pose(0), {sample_pose(1), sample_pose(2)},
                 {{0.5}, {1.5, 2.5}}};
  } else if constexpr (std::is_same_v<T, p::Event>) {
    return sample_event();
  } else if constexpr (std::is_same_v<T, p::RemoteException>) {
    return p::RemoteException("home::NoSuchChannel", "channel 99 does not exist",
                              p::Properties().set("channel", std::int32_t{99}));
  } else if constexpr (std::is_same_v<T, Alarm>) {
    return Alarm{3, "kitchen"};
  } else if constexpr (std::is_same_v<T, std::vector<p::Event>>) {
    return {sample_event(), p::Event("Empty")};
  } else {
    static_assert(std::is_same_v<T, std::vector<p::ObjectRef>>);
    return {p::ObjectRef{"a", "/x", "t"}, p::ObjectRef{}};
  }
}

void write_sample(p::Writer& w, ReadSequence::Step step) {
  visit_kind(step.kind, [&](auto what) {
    using W = decltype(what);
    if constexpr (std::is_same_v<W, Special>) {
      switch (what.kind) {
        case ReadKind::properties:
          p::Properties().set("x", 1.0).set("name", std::string("tv")).encode(w);
          return;
        case ReadKind::value:
          p::Value::of(sample_pose(5)).encode(w);
          return;
        default:
          p::encode_tagged(w, sample(Bare<std::vector<p::ObjectRef>>{}));
          return;
      }
    } else {
      const auto v = sample(what);
      if (step.tagged) {
        p::encode_tagged(w, v);
      } else {
        p::Codec<typename W::type>::encode(w, v);
      }
    }
  });
}

Bytes request(p::RmiCode code, std::string_view path, std::string_view method) {
  Bytes b;
  p::Writer w(b);
  w.u8(0);  // mode byte of payload_fuzz: RMI message
  w.u8(static_cast<std::uint8_t>(code));
  w.u32(code == p::RmiCode::notify ? 0 : 17);
  w.str(path);
  w.str(method);
  return b;
}

template <class... A>
void write_call(const fs::path& dir, std::string_view method, const A&... args) {
  const bool oneway = method == FuzzApi::log.name();
  Bytes b = request(oneway ? p::RmiCode::notify : p::RmiCode::call, kServantPath, method);
  p::Writer w(b);
  w.u8(static_cast<std::uint8_t>(sizeof...(A)));
  (p::encode_tagged(w, args), ...);
  write(dir / fmt::format("rmi_{}_{}.bin", oneway ? "notify" : "call", method), b);
}

void make_payload_corpus(const fs::path& dir) {
  write_call(dir, FuzzApi::add.name(), std::int32_t{2}, std::int32_t{40});
  write_call(dir, FuzzApi::echo_pose.name(), sample_pose(3));
  write_call(dir, FuzzApi::waypoints.name(), sample(Bare<Route>{}), Color::red);
  write_call(dir, FuzzApi::join.name(), std::string("a"), std::vector<std::string>{"b", "c"});
  write_call(dir, FuzzApi::store.name(), sample(Bare<p::Binary>{}), p::StreamRef{3});
  write_call(dir, FuzzApi::listen.name(), sample(Bare<p::Ref<Listener>>{}));
  write_call(dir, FuzzApi::relay.name(), sample_event(), Alarm{2, "hall"});
  write_call(dir, FuzzApi::fail.name(), std::string("on purpose"));
  write_call(dir, FuzzApi::now.name());
  write_call(dir, FuzzApi::log.name(), std::string("hello"), 0.5, true, std::int16_t{-3},
             std::uint8_t{9}, 2.5F, std::vector<bool>{true, false});
  write(dir / "rmi_call_no_servant.bin", request(p::RmiCode::call, "/nobody", "add"));

  // REPLY: the first byte names the result type the caller expects.
  for (std::uint32_t k = 0; k < kReadKinds; ++k) {
    Bytes b;
    p::Writer w(b);
    w.u8(static_cast<std::uint8_t>(k));
    w.u8(static_cast<std::uint8_t>(p::RmiCode::reply));
    w.u32(17);
    write_sample(w, {static_cast<ReadKind>(k), true});
    if (visit_kind(static_cast<ReadKind>(k), [](auto what) {
          return std::is_same_v<decltype(what), Special>;
        })) {
      b.resize(6);
      b.push_back(std::byte{0});  // void
    }
    write(dir / fmt::format("rmi_reply_{:02}.bin", k), b);
  }

  Bytes error;
  p::Writer ew(error);
  ew.u8(0);
  ew.u8(static_cast<std::uint8_t>(p::RmiCode::error));
  ew.u32(17);
  ew.u8(static_cast<std::uint8_t>(p::ErrorKind::failed));
  p::Codec<p::RemoteException>::encode(ew, sample(Bare<p::RemoteException>{}));
  write(dir / "rmi_error.bin", error);

  const auto stream_op = [&](p::StreamOp op, auto&& body, std::string_view name) {
    Bytes b;
    p::Writer w(b);
    w.u8(0);
    w.u8(static_cast<std::uint8_t>(p::RmiCode::stream));
    w.u32(5);
    w.u8(static_cast<std::uint8_t>(op));
    body(w);
    write(dir / fmt::format("rmi_stream_{}.bin", name), b);
  };
  stream_op(p::StreamOp::data, [](p::Writer& w) { w.str("chunk of bytes"); }, "data");
  stream_op(p::StreamOp::pull, [](p::Writer& w) { w.u32(65536); }, "pull");
  stream_op(p::StreamOp::end, [](p::Writer&) {}, "end");
  stream_op(p::StreamOp::cancel, [](p::Writer& w) { w.str("reader gone"); }, "cancel");
  stream_op(p::StreamOp::abort, [](p::Writer& w) { w.str("writer gone"); }, "abort");

  // Read sequences: valid values for the first reads of a spread of first bytes.
  for (unsigned seed = kRmiModes; seed < 256; seed += 7) {
    Bytes b;
    p::Writer w(b);
    w.u8(static_cast<std::uint8_t>(seed));
    ReadSequence sequence(static_cast<std::uint8_t>(seed));
    for (int i = 0; i < 6; ++i) write_sample(w, sequence.next());
    write(dir / fmt::format("sequence_{:03}.bin", seed), b);
  }
}

// --- coros_decoder_fuzz: one datagram of each kind ------------------------------------------

void make_coros_corpus(const fs::path& dir) {
  const co::Place a{"office_101", 1.5, -2.25};
  const co::Place b{"office_112", 30, 4};
  const auto put = [&](const auto& message) {
    const std::string name(co::to_string(std::remove_cvref_t<decltype(message)>::kCode));
    write(dir / (name + ".bin"), co::encode_datagram("robot1", message));
  };
  put(co::HelloMessage{"robot1", "127.0.0.1", 40001, "robot", "idle", 1.7e9, 3.5, 4.5, 2});
  put(co::AuctionMessage{"user-1", 2, "user", a, b, 400, {"robot3", "robot4"}});
  put(co::BidMessage{"user-1", 2, "robot1", 12.5});
  put(co::DeclineMessage{"user-1", 2, "robot3", "no path to kitchen"});
  put(co::AwardMessage{"user-1", 2, "robot1", a, b, 12.5});
  put(co::AwardAckMessage{"user-1", 2, "robot1", false, "busy"});
  put(co::RevokeMessage{"user-1", 2, "robot1"});
  put(co::TaskStatusMessage{"user-1", 2, "robot1", "user", "to_pickup", 3.25, 1.7e9});
  put(co::ResultMessage{"user-1", 2, "robot1", true, 20.5, 41.0, "delivered"});
  put(co::ResultAckMessage{"user-1", 2, "robot1"});
  // Version 2: the same bytes, another version and an authentication trailer (tag not valid).
  Bytes signed_bid = co::encode_datagram("robot2", co::BidMessage{"user-1", 1, "robot2", 3.5});
  signed_bid[2] = std::byte{co::kAuthenticatedVersion};
  const Bytes trailer = filled(co::kAuthTrailerSize, 77);
  signed_bid.insert(signed_bid.end(), trailer.begin(), trailer.end());
  write(dir / "BID_version2.bin", signed_bid);
}

// --- text seeds ------------------------------------------------------------------------------

void copy_files(const fs::path& from, std::string_view extension, const fs::path& to,
                std::string_view prefix) {
  std::vector<fs::path> files;
  for (const auto& entry : fs::directory_iterator(from)) {
    if (entry.is_regular_file() && entry.path().extension() == extension) {
      files.push_back(entry.path());
    }
  }
  for (const fs::path& f : files) {
    write_text(to / (std::string(prefix) + f.filename().string()), read_text(f));
  }
}

// An IDL file with the files it may include appended as `//@file NAME` sections.
void bundle_idl(const fs::path& main, const std::vector<std::pair<std::string, fs::path>>& others,
                const fs::path& out) {
  std::string text = read_text(main);
  for (const auto& [name, path] : others) {
    text += "\n//@file " + name + "\n" + read_text(path);
  }
  write_text(out, text);
}

void make_idl_corpus(const fs::path& repo, const fs::path& dir) {
  const fs::path testdata = repo / "tools/planet-idl/testdata";
  copy_files(repo / "idl", ".idl", dir, "idl_");
  copy_files(testdata, ".idl", dir, "testdata_");
  copy_files(testdata / "imports", ".idl", dir, "imports_");
  copy_files(testdata / "bad", ".idl", dir, "bad_");
  bundle_idl(repo / "idl/home.idl", {{"device.idl", repo / "idl/device.idl"}},
             dir / "bundle_idl_home.idl");
  const std::vector<std::pair<std::string, fs::path>> fixtures = {
      {"types.idl", testdata / "types.idl"},
      {"imports/geometry.idl", testdata / "imports/geometry.idl"}};
  bundle_idl(testdata / "home.idl", fixtures, dir / "bundle_testdata_home.idl");
  bundle_idl(testdata / "names.idl", fixtures, dir / "bundle_testdata_names.idl");
  bundle_idl(testdata / "types.idl", {fixtures[1]}, dir / "bundle_testdata_types.idl");
}

void make_policy_corpus(const fs::path& repo, const fs::path& dir) {
  copy_files(repo / "src/control/testdata", ".xml", dir, "control_");
  write_text(dir / "paper_home.xml", read_text(repo / "examples/smart_home/paper_home.xml"));
  write_text(dir / "tutorial_cooling.xml", read_text(repo / "examples/tutorial/cooling.xml"));
  write_text(dir / "night_light.xml", read_text(repo / "apps/icars/testdata/night_light.xml"));
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 3) {
    std::fprintf(stderr, "usage: %s REPO_ROOT CORPUS_DIR\n", argv[0]);
    return 2;
  }
  const fs::path repo(argv[1]);
  const fs::path corpus(argv[2]);
  try {
    make_frame_corpus(fresh_dir(corpus / "frame_decoder_fuzz"));
    make_payload_corpus(fresh_dir(corpus / "payload_fuzz"));
    make_coros_corpus(fresh_dir(corpus / "coros_decoder_fuzz"));
    make_idl_corpus(repo, fresh_dir(corpus / "idl_parser_fuzz"));
    make_policy_corpus(repo, fresh_dir(corpus / "policy_parser_fuzz"));
  } catch (const std::exception& e) {
    std::fprintf(stderr, "fuzz_make_corpus: %s\n", e.what());
    return 1;
  }
  std::printf("fuzz_make_corpus: wrote the seeds to %s\n", corpus.string().c_str());
  return 0;
}
