#include "apps/viewer/viewer_server.h"

#include <nlohmann/json.hpp>

#include <sstream>

#include "apps/viewer/viewer_files.h"
#include "apps/viewer/viewer_protocol.h"
#include "apps/viewer/viewer_quality.h"
#include "apps/viewer/viewer_replies.h"
#include "apps/viewer/viewer_state.h"
#include "hybrid_octree/surface_export.h"
#include "render/patient_view.h"
#include "render/scene_pool.h"
#include "render/scene_renderer.h"
#include "surface/mesh_io.h"
#include "surface/mesh_ops.h"
#include "volume/core/error.h"
#include "volume/core/file_util.h"
#include "volume/dicomweb.h"

namespace hyb::viewer {

namespace net = boost::asio;
using tcp = net::ip::tcp;

namespace {

std::string keyOf(const std::string& path, const std::string& series) { return series.empty() ? path : path + "#" + series; }

// A mesh of @p scene's isosurface at @p iso in patient coordinates, as `export --surface octree` writes it.
std::string meshFile(const Scene& scene, float iso, const std::string& format) {
  std::ostringstream log;  // export's report: the page shows none
  const TriangleMesh mesh = exportSurface(scene, ExportRequest{iso, "octree"}, nullptr, log).mesh;
  const Volume& v = scene.volume;
  if (mesh.triangles.empty()) HYB_THROW(ValueError, "iso: no surface at ", iso, " (the data's values are ", v.minValue(), " to ", v.maxValue(), ")");
  return meshBytes(mesh, *meshFormatOf("surface." + format), MeshWriteOptions{false, "LPS"});
}

}  // namespace

void ServerState::log(const std::string& line) {
  if (options.log) *options.log << "view     " << line << std::endl;
}

void ServerState::send(uint64_t viewer, const std::string& message) {
  if (const auto c = clients.find(viewer); c != clients.end()) c->second->send(message, false);
}

// What the page's menu calls scene @p key (a DICOM series by its directory, modality, slices and
// description, not its UID); the key itself when the listing has no such entry.
std::string ServerState::labelOf(const std::string& key) const {
  for (const DataEntry& e : listing)
    if (keyOf(e.path, e.series) == key) return e.label;
  return key;
}

// @p text with the data directory's own path left out of the paths it names (the page knows
// its volumes by their paths in that directory).
std::string ServerState::inDataDirTerms(std::string text) const {
  if (dataRoot.empty()) return text;
  const std::string prefix = dataRoot + "/";
  for (size_t at = text.find(prefix); at != std::string::npos; at = text.find(prefix, at)) text.erase(at, prefix.size());
  return text;
}

ScenePool::Events ServerState::poolEvents() {
  ScenePool::Events e;
  e.loading = [this](uint64_t viewer, const std::string& key, const std::string& task, double fraction) {
    send(viewer, LoadingReply{key, task, fraction}.text());
  };
  e.opened = [this](uint64_t viewer, const std::string& key, const SceneSummary* summary, const std::string& error) {
    const auto c = clients.find(viewer);
    if (c == clients.end()) return;
    if (!summary) {
      if (c->second->sceneKey == key) c->second->showScene("");  // (its preview was shown: closed)
      c->second->send(OpenFailedReply{key, "cannot open " + labelOf(key) + ": " + inDataDirTerms(error)}.text(), false);
      return;
    }
    c->second->showScene(key);
    c->second->send(InfoReply{*summary, pool->readySurfaces(key), listing, !options.dataDir.empty(), pacsShown(), meshes}.text(), false);
  };
  e.surface = [this](uint64_t viewer, const std::string& key, float iso, ScenePool::SurfaceState state, const std::string& task, double fraction) {
    send(viewer, SurfaceReply{key, iso, state, task, fraction}.text());
  };
  e.wake = [this] { wake.notify_all(); };
  return e;
}

void ServerState::renderLoop() {
  std::unique_lock<std::mutex> lock(mutex);
  auto ready = [&] { return stopping || pool->hasWork() || FrameScheduler::hasWork(clients); };
  while (!stopping) {
    if (const std::optional<ScenePool::Clock::time_point> due = pool->nextRelease())
      wake.wait_until(lock, *due, ready);
    else
      wake.wait(lock, ready);
    if (stopping) break;
    for (const std::string& key : pool->collect(lock)) FrameScheduler::refineAgain(clients, key);
    scheduler->serveNext(clients, lock);  // a large final frame gives way between its bands
  }
  // The renderers' OpenGL contexts are this thread's: destroyed here once the network and export
  // threads, which use the pool, have ended, and without the mutex (the pool's threads still want
  // it while they stop).
  wake.wait(lock, [&] { return othersStopped; });
  std::unique_ptr<ScenePool> gone = std::move(pool);
  lock.unlock();
  gone.reset();
}

// Slow work on a thread of its own (frames go on meanwhile).
void ServerState::sideLoop() {
  std::unique_lock<std::mutex> lock(mutex);
  while (!stopping) {
    wake.wait(lock, [&] { return stopping || !sideJobs.empty(); });
    if (stopping) break;
    const auto job = std::move(sideJobs.front());
    sideJobs.pop_front();
    job(lock);
  }
}

void ServerState::queueExport(ExportJob e) {
  const std::lock_guard<std::mutex> lock(mutex);
  sideJobs.push_back([this, e = std::move(e)](std::unique_lock<std::mutex>& held) {
    const Scene* scene = pool->pin(e.sceneKey);
    if (!scene) {
      const SceneSummary* preview = pool->summary(e.sceneKey);
      e.reply("", preview ? labelOf(e.sceneKey) + " is still loading (a preview is shown): its mesh can be exported once it is open" : "no such scene");
      return;
    }
    held.unlock();
    std::string body, error;
    try {
      body = meshFile(*scene, e.iso, e.format);
    } catch (const std::exception& ex) {
      error = ex.what();
    }
    held.lock();
    pool->unpin(e.sceneKey);
    e.reply(std::move(body), std::move(error));
  });
  wake.notify_all();
}

std::string ServerState::pacsShown() const { return options.pacs.empty() ? "" : redactUrl(options.pacs); }

void ServerState::searchPacs(const std::shared_ptr<Client>& c, const PacsSearchRequest& search) {
  if (options.pacs.empty()) {
    c->send(errorMessage("pacs: the server has no PACS (start it with --pacs http(s)://HOST:PORT/ROOT)"), false);
    return;
  }
  const std::lock_guard<std::mutex> lock(mutex);
  sideJobs.push_back([this, c, search](std::unique_lock<std::mutex>& held) {
    held.unlock();
    std::vector<DicomWebSeries> found;
    std::string error;
    try {
      found = queryDicomWeb(options.pacs, DicomWebQuery{search.patient, search.studyDate, search.modality});
    } catch (const std::exception& e) {
      error = e.what();
    }
    held.lock();
    if (!error.empty()) {
      c->send(errorMessage("pacs: " + error), false);
      return;
    }
    if (pacsLabels.size() > 10000) pacsLabels.clear();  // (a bound: labels only name what is opened)
    for (const DicomWebSeries& s : found) pacsLabels[s.url] = PacsReply::label(s);
    c->send(PacsReply{found}.text(), false);
  });
  wake.notify_all();
}

bool ServerState::addClient(const std::shared_ptr<Client>& c) {
  const std::lock_guard<std::mutex> lock(mutex);
  if (int(clients.size()) >= options.maxClients) return false;
  c->id = nextClient++;
  clients[c->id] = c;
  if (!defaultScene.empty()) {
    // Told at once while it is open; read again if it was released while no client showed it.
    pool->open(c->id, defaultScene, options.volume, options.series, std::filesystem::path(options.volume).filename().string());
  } else {
    c->send(VolumesReply{listing, pacsShown(), meshes}.text(), false);
  }
  return true;
}

void ServerState::removeClient(const std::shared_ptr<Client>& c) {
  const std::lock_guard<std::mutex> lock(mutex);
  c->open = false;
  clients.erase(c->id);
  pool->leave(c->id);
}

// A series of the server's PACS only: the address names no other host (the server fetches it).
void ServerState::openFromPacs(const std::shared_ptr<Client>& c, const std::string& url) {
  std::string root = options.pacs;
  while (!root.empty() && root.back() == '/') root.pop_back();
  if (root.empty() || url.rfind(root + "/studies/", 0) != 0 || url.find("/series/") == std::string::npos) {
    c->send(errorMessage(root.empty() ? "open: the server has no PACS (start it with --pacs http(s)://HOST:PORT/ROOT)"
                                      : "open: url must be a series of " + redactUrl(root) + " (ROOT/studies/UID/series/UID)"),
            false);
    return;
  }
  const std::lock_guard<std::mutex> lock(mutex);
  const auto label = pacsLabels.find(url);
  pool->open(c->id, url, url, "", label != pacsLabels.end() ? label->second : url.substr(root.size() + 1));
}

void ServerState::open(const std::shared_ptr<Client>& c, const OpenRequest& open) {
  if (!open.url.empty()) {
    openFromPacs(c, open.url);
    return;
  }
  if (options.dataDir.empty()) {
    c->send(errorMessage("open: the server has no data directory (start it with --data-dir)"), false);
    return;
  }
  std::filesystem::path real;
  try {
    real = resolveInDataDir(options.dataDir, open.path);
  } catch (const Error& e) {
    c->send(errorMessage(e.what()), false);
    return;
  }
  const std::lock_guard<std::mutex> lock(mutex);
  pool->open(c->id, keyOf(open.path, open.series), real.string(), open.series, open.path);
}

// A frame's mesh files are paths in the data directory (no other file is read): each replaced by
// the file it names there; why not, when one is not.
std::string ServerState::meshesInDataDir(FrameSettings* settings) const {
  for (FrameSettings::MeshFile& m : settings->meshes) {
    if (options.dataDir.empty()) return "mesh: the server has no data directory (a mesh is a file in it: start the server with --data-dir)";
    try {
      m.path = resolveInDataDir(options.dataDir, m.path).string();
    } catch (const Error& e) {
      return std::string("mesh: ") + e.what();
    }
  }
  return "";
}

void ServerState::onMessage(const std::shared_ptr<Client>& c, const std::string& text) {
  Request request;
  try {
    request = parseRequest(text);
  } catch (const Error& e) {
    c->send(errorMessage(e.what()), false);
    return;
  }
  if (const auto* o = std::get_if<OpenRequest>(&request)) {
    open(c, *o);
    return;
  }
  if (const auto* search = std::get_if<PacsSearchRequest>(&request)) {
    searchPacs(c, *search);
    return;
  }
  auto& frame = std::get<FrameRequest>(request);
  if (const std::string why = meshesInDataDir(&frame.settings); !why.empty()) {
    c->send(errorMessage(why, frame.seq), false);
    return;
  }
  const std::lock_guard<std::mutex> lock(mutex);
  if (c->sceneKey.empty()) {
    c->send(errorMessage("no volume is open (send an open message first)", frame.seq), false);
    return;
  }
  if (!frame.scene.empty() && frame.scene != c->sceneKey) return;  // for the scene shown before: stale
  c->ask(std::move(frame), scheduler->renders());
  wake.notify_all();
}

Server::Server(ServerOptions options) : mImpl(std::make_unique<ServerState>()) {
  ServerState& s = *mImpl;
  s.options = std::move(options);
  s.token = s.options.token.empty() ? makeToken() : s.options.token;
  if (!s.options.loader) HYB_THROW(ValueError, "view: no volume loader");
  if (s.options.volume.empty() && s.options.dataDir.empty() && s.options.pacs.empty())
    HYB_THROW(ValueError, "view: expected a volume, --data-dir or --pacs");
  if (!s.options.dataDir.empty()) {
    s.listing = listDataDir(s.options.dataDir, 500, &s.meshes);
    s.dataRoot = std::filesystem::canonical(s.options.dataDir).string();  // (listDataDir has read it)
  }
  ScenePool::Options po;
  po.loader = s.options.loader;
  po.previewer = s.options.previewer;
  po.textureLimitBytes = s.options.textureLimitBytes;
  po.memoryBytes = s.options.memoryBytes;
  po.releaseAfter = s.options.releaseAfter;
  s.pool = std::make_unique<ScenePool>(s.mutex, std::move(po), s.poolEvents());
  s.scheduler = std::make_unique<FrameScheduler>(*s.pool, s.mutex, s.options.frameTargetMs, [&s](std::string text) { return s.inDataDirTerms(std::move(text)); });
  if (!s.options.volume.empty()) {
    s.defaultScene = keyOf(s.options.volume, s.options.series);
    s.pool->preload(s.defaultScene, s.options.volume, s.options.series, std::filesystem::path(s.options.volume).filename().string());
  }
  boost::system::error_code ec;
  const net::ip::address address = net::ip::make_address(s.options.host, ec);
  if (ec) HYB_THROW(ValueError, "--host '", s.options.host, "': expected an IP address (", ec.message(), ")");
  const tcp::endpoint endpoint(address, s.options.port);
  s.acceptor.open(endpoint.protocol(), ec);
  if (!ec) s.acceptor.set_option(net::socket_base::reuse_address(true), ec);
  if (!ec) s.acceptor.bind(endpoint, ec);
  if (!ec) s.acceptor.listen(net::socket_base::max_listen_connections, ec);
  if (ec) HYB_THROW(IoError, "--port ", s.options.port, ": cannot listen on ", s.options.host, ":", s.options.port, " (", ec.message(), ")");
}

Server::~Server() { stop(); }

uint16_t Server::port() const { return mImpl->acceptor.local_endpoint().port(); }
const std::string& Server::token() const { return mImpl->token; }
std::string Server::url() const {
  const std::string host = mImpl->options.host.find(':') != std::string::npos ? "[" + mImpl->options.host + "]" : mImpl->options.host;
  return "http://" + host + ":" + std::to_string(port()) + "/?token=" + mImpl->token;
}

void Server::start() {
  ServerState& s = *mImpl;
  if (s.started) return;
  s.started = true;
  acceptConnections(s);
  s.renderThread = std::thread([&s] { s.renderLoop(); });
  s.sideThread = std::thread([&s] { s.sideLoop(); });
  s.netThread = std::thread([&s] { s.io.run(); });
}

void Server::run() {
  start();
  if (mImpl->netThread.joinable()) mImpl->netThread.join();
}

void Server::stop() {
  ServerState& s = *mImpl;
  if (s.stopping.exchange(true)) return;
  {
    const std::lock_guard<std::mutex> lock(s.mutex);
    s.wake.notify_all();
  }
  net::post(s.io, [&s] {
    boost::system::error_code ignored;
    s.acceptor.close(ignored);
  });
  s.io.stop();
  for (std::thread* t : {&s.netThread, &s.sideThread})
    if (t->joinable() && t->get_id() != std::this_thread::get_id()) t->join();
  {
    const std::lock_guard<std::mutex> lock(s.mutex);
    s.othersStopped = true;
    s.wake.notify_all();
  }
  if (s.renderThread.joinable() && s.renderThread.get_id() != std::this_thread::get_id()) s.renderThread.join();
  s.pool.reset();  // never started (the render thread destroys it otherwise): no context was made
}

}  // namespace hyb::viewer
