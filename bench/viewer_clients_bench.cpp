// Clients of one viewer server sharing its render thread: with N clients, one asks 2048² final
// frames of the cranium over and over (when N > 1) while the others orbit it, each asking a moving
// frame (512² canvas, ct-bone and the translucent 400 HU surface) as soon as its last one came.
// Prints, per N, the movers' frames per second, their p95 and longest wait from request to frame
// (and the longest after each mover's first frame: the movers' first requests come together and
// queue behind each other; and the longest of the requests sent after the run's first second, once
// every mover's frames are warm), and how many other renders a moving frame waited behind (the
// scheduler's count; docs/viewer.md), and how long the 2048² client waited for its slowest final frame
// (one still being drawn when the run ends is waited for). The longest band is the 2048² frames' (bands drawn after the
// run's end, with no mover left, included).
//
//   hyb_viewer_clients_bench [volume=the cranium] [seconds=15] [clients=1,2,8]
#include <utility>  // (before Boost.Asio, whose headers use std::exchange without it)

#include <boost/asio.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/websocket.hpp>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "apps/viewer/viewer_protocol.h"
#include "apps/viewer/viewer_server.h"
#include "hybrid_octree/hybrid_io.h"

namespace {

namespace net = boost::asio;
namespace beast = boost::beast;
namespace websocket = beast::websocket;
using tcp = net::ip::tcp;
using nlohmann::json;
using Clock = std::chrono::steady_clock;

struct Socket {
  net::io_context io;
  websocket::stream<tcp::socket> ws{io};
  explicit Socket(uint16_t port, const std::string& token) {
    ws.next_layer().connect(tcp::endpoint(net::ip::make_address("127.0.0.1"), port));
    ws.set_option(websocket::stream_base::decorator([port](websocket::request_type& req) {
      req.set(beast::http::field::origin, "http://127.0.0.1:" + std::to_string(port));
    }));
    ws.read_message_max(64 << 20);
    ws.handshake("127.0.0.1:" + std::to_string(port), "/ws?token=" + token);
  }
  json next() {
    beast::flat_buffer buffer;
    ws.read(buffer);
    const std::string data = beast::buffers_to_string(buffer.data());
    if (ws.got_text()) return json::parse(data);
    std::string header, image;
    hyb::viewer::splitFrameMessage(data, &header, &image);
    return json::parse(header);
  }
  // The frame answering @p seq (its final one when @p final), skipping other messages.
  json frame(uint64_t seq, bool final) {
    for (;;) {
      json m = next();
      if (m["type"] == "error") throw std::runtime_error(m.dump());
      if (m["type"] == "frame" && m["seq"] == seq && (!final || m["quality"] == "final")) return m;
    }
  }
  void send(const json& m) {
    ws.text(true);
    ws.write(net::buffer(m.dump()));
  }
};

json request(const json& info, uint64_t seq, bool interacting, int pixels, double azimuth) {
  const json& c = info["center"];
  const double a = azimuth * 3.14159265358979 / 180.0, r = 600.0;
  return {{"type", "frame"},       {"seq", seq},
          {"interacting", interacting},
          {"eye", {c[0].get<double>() + r * std::sin(a), c[1].get<double>() - r * std::cos(a), c[2].get<double>()}},
          {"center", c},           {"up", {0, 0, 1}},
          {"fov", 30},             {"size", {pixels, pixels}},
          {"preset", "ct-bone"},   {"iso", 400},
          {"surface_color", {0.95, 0.92, 0.85, 0.4}}};
}

double percentile(std::vector<double> v, double p) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, size_t(p * double(v.size())))];
}

}  // namespace

int main(int argc, char** argv) {
  const std::string volume = argc > 1 ? argv[1] : "/usr/share/doc/invesalius-examples/examples/Cranium.inv3";
  const double seconds = argc > 2 ? std::atof(argv[2]) : 15.0;
  std::vector<int> counts;
  std::istringstream list(argc > 3 ? argv[3] : "1,2,8");
  for (std::string n; std::getline(list, n, ',');) counts.push_back(std::atoi(n.c_str()));

  hyb::viewer::ServerOptions o;
  o.port = 0;
  o.volume = volume;
  o.loader = [](const std::string& path, const std::string& series, const hyb::Progress* progress) {
    return hyb::openScene(hyb::SceneSource{path, nullptr, series, progress}).scene;
  };
  hyb::viewer::Server server(o);
  server.start();
  std::printf("%-8s %10s %10s %12s %12s %10s %14s %12s %10s %14s %12s\n", "clients", "frames/s", "p95 ms", "longest ms", "after 1st", "after 1 s", "waited renders",
              "2048² frames", "2048² s", "longest band", "2048² encode");
  for (const int n : counts) {
    std::vector<std::unique_ptr<Socket>> sockets;
    json info;
    for (int k = 0; k < n; ++k) {
      sockets.push_back(std::make_unique<Socket>(server.port(), server.token()));
      info = sockets.back()->next();
    }
    // The surface built and every client warm before the clock starts.
    for (int k = 0; k < n; ++k) {
      sockets[size_t(k)]->send(request(info, 1, false, 128, 0.0));
      sockets[size_t(k)]->frame(1, true);
    }
    std::atomic<bool> stop{false};
    std::atomic<int> bigFrames{0};
    double longestBand = 0.0, encodeMs = 0.0, bigSeconds = 0.0;  // of the 2048² frames (their thread's only)
    std::vector<std::thread> threads;
    std::vector<std::vector<double>> waits(static_cast<size_t>(n));
    std::vector<double> warmWaitMs(size_t(n), 0.0);  // of the requests sent after the first second
    const auto start = Clock::now();
    std::vector<int> waited(size_t(n), 0);
    const int movers = n > 1 ? n - 1 : 1;
    for (int k = 0; k < n; ++k)
      threads.emplace_back([&, k] {
        Socket& s = *sockets[size_t(k)];
        const bool big = n > 1 && k == 0;
        for (uint64_t seq = 10; !stop; ++seq) {
          const auto t0 = Clock::now();
          s.send(request(info, seq, !big, big ? 2048 : 512, 2.0 * double(seq) + 40.0 * k));
          const json f = s.frame(seq, big);
          if (big) {
            ++bigFrames;
            bigSeconds = std::max(bigSeconds, std::chrono::duration<double>(Clock::now() - t0).count());
            longestBand = std::max(longestBand, f["longestBandMs"].get<double>());
            encodeMs = std::max(encodeMs, f["encodeMs"].get<double>());
            continue;
          }
          waits[size_t(k)].push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
          if (t0 - start > std::chrono::seconds(1)) warmWaitMs[size_t(k)] = std::max(warmWaitMs[size_t(k)], waits[size_t(k)].back());
          waited[size_t(k)] = std::max(waited[size_t(k)], f["waitedRenders"].get<int>());
        }
      });
    std::this_thread::sleep_for(std::chrono::duration<double>(seconds));
    stop = true;
    for (std::thread& t : threads) t.join();
    std::vector<double> all;
    double afterFirst = 0.0;  // (the movers' first requests come together and queue behind each other)
    int mostWaited = 0;
    const double afterSecond = *std::max_element(warmWaitMs.begin(), warmWaitMs.end());
    for (int k = n > 1 ? 1 : 0; k < n; ++k) {
      all.insert(all.end(), waits[size_t(k)].begin(), waits[size_t(k)].end());
      if (waits[size_t(k)].size() > 1) afterFirst = std::max(afterFirst, *std::max_element(waits[size_t(k)].begin() + 1, waits[size_t(k)].end()));
      mostWaited = std::max(mostWaited, waited[size_t(k)]);
    }
    std::printf("%-8d %10.1f %10.0f %12.0f %12.0f %10.0f %14d %12d %10.1f %14.0f %12.0f\n", n, double(all.size()) / seconds / movers, percentile(all, 0.95),
                percentile(all, 1.0), afterFirst, afterSecond, mostWaited, bigFrames.load(), bigSeconds, longestBand, encodeMs);
  }
  server.stop();
  return 0;
}
