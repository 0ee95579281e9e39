// The viewer server's state, shared by its three parts (internal to apps/viewer): the scenes and
// clients (viewer_server.cpp), the frame scheduler (frame_scheduler.h) and the connections
// (viewer_connection.cpp).
#pragma once

#include <utility>  // (before Boost.Asio, whose headers use std::exchange without it)

#include <boost/asio.hpp>

#include <atomic>
#include <condition_variable>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "apps/viewer/frame_scheduler.h"
#include "apps/viewer/viewer_files.h"
#include "apps/viewer/viewer_server.h"

namespace hyb::viewer {

/// A mesh of a scene's isosurface asked for over HTTP, made on the side thread; @p reply gets the
/// file's bytes or why there are none.
struct ExportJob {
  std::string sceneKey;
  float iso = 0.0f;
  std::string format;
  std::function<void(std::string body, std::string error)> reply;
};

struct ServerState {
  ServerOptions options;
  std::string token;
  boost::asio::io_context io{1};
  boost::asio::ip::tcp::acceptor acceptor{io};
  std::thread netThread, renderThread, sideThread;
  std::atomic<bool> stopping{false};
  bool started = false;
  bool othersStopped = false;  ///< the network and side threads have ended (under the mutex)

  // Work shared by the threads, and the pool's state: under this mutex.
  std::mutex mutex;
  std::condition_variable wake;
  Clients clients;
  std::unique_ptr<ScenePool> pool;
  std::unique_ptr<FrameScheduler> scheduler;  ///< of the pool's scenes, on the render thread
  std::string defaultScene;  ///< the --volume scene's key, or empty
  /// Slow work beside the frames (mesh exports, PACS searches), in order on the side thread: each
  /// is called with the mutex held and may unlock it while it works.
  std::deque<std::function<void(std::unique_lock<std::mutex>&)>> sideJobs;
  std::map<std::string, std::string> pacsLabels;  ///< what searches called the series found, by address
  uint64_t nextClient = 1;
  std::vector<DataEntry> listing;  ///< the data directory's volumes, listed at start
  std::vector<std::string> meshes; ///< ... and its mesh files
  std::string dataRoot;            ///< the data directory, every link resolved ("" without one)

  void log(const std::string& line);

  // The network thread's calls (viewer_server.cpp).
  /// False when the server has its maximum of clients already.
  bool addClient(const std::shared_ptr<Client>& c);
  void removeClient(const std::shared_ptr<Client>& c);
  void onMessage(const std::shared_ptr<Client>& c, const std::string& text);
  void queueExport(ExportJob job);
  void searchPacs(const std::shared_ptr<Client>& c, const PacsSearchRequest& search);

  // The threads' loops.
  void renderLoop();
  void sideLoop();
  /// The pool's events: each goes to the client it concerns only (under the mutex).
  ScenePool::Events poolEvents();
  /// @p text with the data directory's own path left out of the paths it names.
  std::string inDataDirTerms(std::string text) const;

 private:
  void send(uint64_t viewer, const std::string& message);
  std::string labelOf(const std::string& key) const;
  std::string meshesInDataDir(FrameSettings* settings) const;
  void open(const std::shared_ptr<Client>& c, const OpenRequest& open);
  void openFromPacs(const std::shared_ptr<Client>& c, const std::string& url);
  std::string pacsShown() const;
};

/// Accepts connections on @p s's acceptor until it is closed: each an HTTP session that serves the
/// page and the mesh export, or upgrades to the client's WebSocket (viewer_connection.cpp).
void acceptConnections(ServerState& s);

}  // namespace hyb::viewer
