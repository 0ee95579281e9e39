// `hybrid-octree view`: an HTTP and WebSocket server (Boost.Beast) that serves the viewer's page
// and renders its frames through one SceneRenderer per open volume. Threads: one for the network
// (every socket, asynchronous), one that renders (it owns the OpenGL contexts) and, while they
// run, one that loads a volume and one per scene that builds an isosurface in the background.
//
// Each client (one WebSocket) keeps its own view, look and adaptive quality; the render thread
// serves the clients with work in turn, always the newest request of each (a request that arrives
// while another of the same client waits replaces it: stale frames are dropped, never queued).
// Every HTTP request and the socket need the access token (as ?token= or the cookie the page gets).
#pragma once

#include <chrono>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <ostream>
#include <string>

#include "hybrid_octree/hybrid_io.h"
#include "render/scene_pool.h"

namespace hyb::viewer {

/// Reads a volume (or scene file) and builds what the renderer needs: path and DICOM series, with
/// the load's progress (which throws to stop it when nobody waits for it any more).
using SceneLoader = ScenePool::Loader;

struct ServerOptions {
  std::string host = "127.0.0.1";
  uint16_t port = 8080;                ///< 0: any free port (see Server::port)
  std::string volume;                  ///< opened for every client at start; empty with a data directory
  std::string series;                  ///< its DICOM series, or empty
  std::filesystem::path dataDir;       ///< the page lists and opens volumes under it; empty: none
  /// A PACS's DICOMweb root (http(s)://HOST:PORT/ROOT) the page searches and opens series of (the
  /// loader reads their addresses); empty: none.
  std::string pacs;
  std::string token;                   ///< empty: a random one
  uint64_t textureLimitBytes = 1ull << 29;  ///< brick textures each scene keeps between frames
  uint64_t memoryBytes = 0;            ///< --memory: each paged scene's octrees, surfaces and block cache (0: the loader's bound)
  double frameTargetMs = 80.0;         ///< interactive frames aim at this time (render and encode)
  int maxClients = 8;
  /// A volume no client shows is released this long after the last one left it.
  std::chrono::milliseconds releaseAfter{10000};
  /// A message whose first bytes came this long ago and is not complete closes its socket.
  std::chrono::milliseconds messageTimeout{10000};
  SceneLoader loader;
  /// A coarse scene shown while the loader reads a volume that takes long (a PACS series); may be empty.
  ScenePool::Previewer previewer;
  std::ostream* log = nullptr;         ///< one line per connection and error; null: silent
};

struct ServerState;

class Server {
 public:
  /// Binds the socket and opens ServerOptions::volume (when given) before returning.
  /// @throw IoError when the address cannot be bound; the loader's errors for the volume.
  explicit Server(ServerOptions options);
  ~Server();
  Server(const Server&) = delete;
  Server& operator=(const Server&) = delete;

  uint16_t port() const;
  const std::string& token() const;
  /// http://host:port/?token=...
  std::string url() const;

  /// Serves until stop() (from another thread or a signal handler's thread).
  void run();
  /// Serves on background threads and returns (tests).
  void start();
  /// Closes every connection and stops the threads; safe to call twice.
  void stop();

 private:
  std::unique_ptr<ServerState> mImpl;
};

}  // namespace hyb::viewer
