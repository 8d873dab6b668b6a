// Direction of arrival: GCC-PHAT delays to a fraction of a sample, and SRP-PHAT bearings from a
// four-microphone circle in a clean field and in a reverberant, noisy room (acoustics.h).
#include "icars/audio/direction.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <numbers>

#include "icars/audio/acoustics.h"
#include "test_signals.h"

namespace icars::audio {
namespace {

using namespace testing;
constexpr double kPi = std::numbers::pi;

double radians(double degrees) { return degrees * kPi / 180.0; }
double degrees(double radians) { return radians * 180.0 / kPi; }
double angle_error_deg(double a, double b) {
  return std::abs(degrees(std::remainder(a - b, 2 * kPi)));
}

// A far-field source at `bearing` heard by `mics`: each channel delayed by its own fractional
// delay (the sound reaches a microphone further along the bearing earlier).
AudioBlock far_field(const Signal& source, double bearing, const std::vector<MicPosition>& mics) {
  std::vector<std::vector<float>> channels;
  for (const auto& m : mics) {
    const double lead = (m.x * std::cos(bearing) + m.y * std::sin(bearing)) / kSpeedOfSound;
    channels.push_back(delayed(source.samples, 20.0 - lead * source.sample_rate));
  }
  return interleave(channels, source.sample_rate);
}

// The paths from a talker `distance` metres away at `bearing` to each microphone.
std::vector<Path> paths_to(const std::vector<MicPosition>& mics, double bearing, double distance,
                           double level_db) {
  const double sx = distance * std::cos(bearing), sy = distance * std::sin(bearing);
  std::vector<Path> paths;
  for (const auto& m : mics) paths.push_back({std::hypot(sx - m.x, sy - m.y), level_db});
  return paths;
}

TEST(Direction, CircularArrayStartsStraightAhead) {
  const auto mics = circular_array(4, 0.1);
  ASSERT_EQ(mics.size(), 4u);
  EXPECT_NEAR(mics[0].x, 0.1, 1e-12);
  EXPECT_NEAR(mics[0].y, 0.0, 1e-12);
  EXPECT_NEAR(mics[1].x, 0.0, 1e-12);
  EXPECT_NEAR(mics[1].y, 0.1, 1e-12);  // counter-clockwise: the second one on the left
  EXPECT_NEAR(mics[2].x, -0.1, 1e-12);
}

TEST(Direction, GccPhatFindsAFractionOfASample) {
  const Signal x = white_noise(0.5, -20, 1);
  for (double delay : {3.37, -2.81, 0.5, 0.0, 7.9}) {
    const auto shifted = delayed(x.samples, delay);
    const double found = gcc_phat_delay(x.samples, shifted, kSpeechRate, 0.001);
    EXPECT_NEAR(found * kSpeechRate, delay, 0.05) << delay;
  }
  // Outside +-max_delay the peak is not looked for.
  const auto far = delayed(x.samples, 12.0);
  EXPECT_LE(std::abs(gcc_phat_delay(x.samples, far, kSpeechRate, 5.0 / kSpeechRate)) * kSpeechRate,
            5.0 + 1e-9);
}

TEST(Direction, FindsFarFieldNoiseBurstsEveryThirtyDegrees) {
  const auto mics = circular_array(4, 0.08);
  const Signal source = noise_bursts(4, 0.2, 0.1, -20, 2);
  double worst = 0;
  for (int deg = -150; deg <= 180; deg += 30) {
    const auto estimate = estimate_direction(far_field(source, radians(deg), mics), mics);
    ASSERT_TRUE(estimate.valid);
    const double error = angle_error_deg(estimate.bearing, radians(deg));
    worst = std::max(worst, error);
    EXPECT_LT(error, 2.0) << deg << " degrees";
    EXPECT_GT(estimate.confidence, 0.5) << deg << " degrees";
    EXPECT_GT(estimate.bearing, -kPi);
    EXPECT_LE(estimate.bearing, kPi);
  }
  std::printf("[ direction] anechoic, far field: worst error %.2f degrees\n", worst);
}

TEST(Direction, FindsATalkerInAReverberantNoisyRoom) {
  // A 4-microphone circle of 6 cm radius; noise bursts at 60 dB SPL from 1.5 m and from 3 m, in
  // rooms whose reverberation outweighs the direct sound there (critical distance 1 m), over
  // background noise. The product needs 20 degrees; this asks for 10.
  struct Room {
    double distance, rt60, noise_db;
  };
  const auto mics = circular_array(4, 0.06);
  const Signal source = noise_bursts(5, 0.15, 0.1, -20, 3);
  for (const Room r : {Room{1.5, 0.4, 30}, Room{3.0, 0.6, 40}}) {
    double worst = 0, total = 0;
    int count = 0;
    for (int deg = -150; deg <= 180; deg += 30) {
      RoomSound room;
      room.rt60 = r.rt60;
      room.critical_distance = 1.0;
      room.noise_db = r.noise_db;
      room.seed = static_cast<std::uint64_t>(deg + 1000);
      const AudioBlock audio = render(source, paths_to(mics, radians(deg), r.distance, 60), room);
      const auto estimate = estimate_direction(audio, mics);
      ASSERT_TRUE(estimate.valid);
      const double error = angle_error_deg(estimate.bearing, radians(deg));
      worst = std::max(worst, error);
      total += error;
      ++count;
      EXPECT_LT(error, 10.0) << r.distance << " m, " << deg << " degrees, found "
                             << degrees(estimate.bearing);
      EXPECT_GT(estimate.confidence, 0.02) << deg << " degrees";
    }
    std::printf(
        "[ direction] %.1f m, RT60 %.1f s, noise %.0f dB SPL: mean error %.2f, worst %.2f "
        "degrees\n",
        r.distance, r.rt60, r.noise_db, total / count, worst);
  }
}

TEST(Direction, TwoMicrophonesReportTheFrontImage) {
  // A pair side by side (on the y axis) hears a source behind as its mirror image in front.
  const std::vector<MicPosition> pair = {{0.0, 0.05}, {0.0, -0.05}};
  const Signal source = noise_bursts(3, 0.2, 0.1, -20, 4);
  for (const auto& [actual, reported] : std::vector<std::pair<double, double>>{
           {45, 45}, {-30, -30}, {150, 30}, {-120, -60}, {-150, -30}, {60, 60}}) {
    const auto estimate = estimate_direction(far_field(source, radians(actual), pair), pair);
    ASSERT_TRUE(estimate.valid);
    EXPECT_LE(std::abs(estimate.bearing), kPi / 2 + 1e-9) << actual;
    EXPECT_LT(angle_error_deg(estimate.bearing, radians(reported)), 3.0)
        << actual << " degrees, found " << degrees(estimate.bearing);
  }
  // A pair on the x axis (circular_array(2, r)) tells front from back but not left from
  // right: it reports the image on the left.
  const auto fore_aft = circular_array(2, 0.05);
  const auto estimate = estimate_direction(far_field(source, radians(-120), fore_aft), fore_aft);
  EXPECT_LT(angle_error_deg(estimate.bearing, radians(120)), 3.0) << degrees(estimate.bearing);
}

// Delay-and-sum towards the source lines the channels up: the steered signal is the source
// (delayed by the common 20 samples), while steering the other way smears high frequencies.
TEST(Direction, SteeringTowardsASourceLinesItsChannelsUp) {
  const auto mics = circular_array(4, 0.08);
  const Signal source = white_noise(0.5, -20, 7);
  for (const double deg : {0.0, 30.0, 135.0, -100.0}) {
    const AudioBlock heard = far_field(source, radians(deg), mics);
    const Signal towards = steer_towards(heard, mics, radians(deg));
    const Signal away = steer_towards(heard, mics, radians(deg + 180));
    ASSERT_EQ(towards.samples.size(), heard.frames());
    const auto reference = delayed(source.samples, 20.0);
    double error = 0, energy = 0;
    for (std::size_t i = 100; i + 100 < reference.size(); ++i) {
      const double e = towards.samples[i] - reference[i];
      error += e * e;
      energy += static_cast<double>(reference[i]) * reference[i];
    }
    EXPECT_LT(error / energy, 0.01) << deg << " degrees: the aligned sum is the source";  // within 20 dB
    EXPECT_GT(rms(towards.samples), 1.3 * rms(away.samples)) << deg << " degrees";
  }
  // Nothing to steer, and audio that does not fit the array.
  AudioBlock empty;
  empty.format = {kSpeechRate, 4};
  EXPECT_TRUE(steer_towards(empty, mics, 0).samples.empty());
  AudioBlock three;
  three.format = {kSpeechRate, 3};
  three.samples.assign(3 * 160, 0);
  EXPECT_THROW(steer_towards(three, mics, 0), AudioError);
}

TEST(Direction, RefusesAudioThatDoesNotMatchTheArray) {
  const auto mics = circular_array(4, 0.05);
  AudioBlock three;
  three.format = {kSpeechRate, 3};
  three.samples.assign(3 * 1600, 0);
  EXPECT_THROW(estimate_direction(three, mics), AudioError);
  AudioBlock mono;
  mono.samples.assign(1600, 0);
  EXPECT_THROW(estimate_direction(mono, {MicPosition{}}), AudioError);
  try {
    estimate_direction(three, mics);
  } catch (const AudioError& e) {
    EXPECT_NE(std::string(e.what()).find("3 channels for 4 microphones"), std::string::npos)
        << e.what();
  }
}

TEST(Direction, SilenceHasNoDirectionAndDiffuseNoiseLittleConfidence) {
  const auto mics = circular_array(4, 0.05);
  AudioBlock silent;
  silent.format = {kSpeechRate, 4};
  silent.samples.assign(4 * 8000, 0);
  EXPECT_FALSE(estimate_direction(silent, mics).valid);

  RoomSound room;
  room.noise_db = 50;  // independent at each microphone: no direction to find
  const auto noise = estimate_direction(room_noise(1.0, 4, room), mics);
  const auto talker =
      estimate_direction(far_field(noise_bursts(3, 0.2, 0.1, -30, 5), 1.0, mics), mics);
  EXPECT_LT(noise.confidence, 0.2);
  EXPECT_GT(talker.confidence, noise.confidence + 0.3);
}

}  // namespace
}  // namespace icars::audio
