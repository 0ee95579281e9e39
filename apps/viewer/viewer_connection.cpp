// The viewer's connections: one HTTP session per socket (the page's assets, the mesh export, the
// upgrade) and one WebSocket session per client (its messages in, its frames and replies out).
#include "apps/viewer/viewer_state.h"

#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/websocket.hpp>

#include <cmath>
#include <deque>
#include <sstream>

#include "apps/viewer/viewer_files.h"
#include "apps/viewer/viewer_protocol.h"
#include "apps/viewer/viewer_state.h"
#include "surface/mesh_io.h"

namespace hyb::viewer {

namespace net = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
namespace websocket = beast::websocket;
using tcp = net::ip::tcp;

namespace {

// Whether @p req carries the access token, as ?token= or the cookie the page got.
bool authorised(const http::request<http::string_body>& req, const std::string& token) {
  if (const auto q = queryParam(std::string_view(req.target().data(), req.target().size()), "token"); q && tokenMatches(*q, token)) return true;
  const auto cookie = req.find(http::field::cookie);
  if (cookie == req.end()) return false;
  const auto c = cookieValue(std::string_view(cookie->value().data(), cookie->value().size()), "hyb_token");
  return c && tokenMatches(*c, token);
}

// One WebSocket: reads messages into its client; writes the newest frame and every text message.
class WsSession : public std::enable_shared_from_this<WsSession> {
 public:
  WsSession(tcp::socket&& socket, ServerState& server) : mWs(std::move(socket)), mServer(server) {}

  void run(http::request<http::string_body> req) {
    mWs.set_option(websocket::stream_base::timeout::suggested(beast::role_type::server));
    mWs.read_message_max(kMaxMessageBytes);
    mWs.async_accept(req, beast::bind_front_handler(&WsSession::onAccept, shared_from_this()));
  }

 private:
  void onAccept(beast::error_code ec) {
    if (ec) return;
    mClient = std::make_shared<Client>(mServer.options.frameTargetMs);
    std::weak_ptr<WsSession> self = shared_from_this();
    net::any_io_executor executor = mWs.get_executor();
    mClient->send = [self, executor](std::string message, bool binary) {
      net::post(executor, [self, message = std::move(message), binary]() mutable {
        if (auto s = self.lock()) s->queue(std::move(message), binary);
      });
    };
    if (!mServer.addClient(mClient)) {
      // Told why, then closed once the message is out.
      mClient.reset();
      auto me = shared_from_this();
      auto text = std::make_shared<std::string>(errorMessage("the viewer serves " + std::to_string(mServer.options.maxClients) + " clients at most"));
      mWs.text(true);
      mWs.async_write(net::buffer(*text), [me, text](beast::error_code, size_t) {
        me->mWs.async_close(websocket::close_code::try_again_later, [me](beast::error_code) {});
      });
      return;
    }
    mServer.log("client connected");
    read();
  }

  // A message is read in parts as they come: one whose first part came more than
  // ServerOptions::messageTimeout ago closes the socket (a client trickling bytes would otherwise
  // keep its slot for good); an idle socket is left alone (Beast's pings find a peer that is gone).
  void read() { mWs.async_read_some(mBuffer, kMaxMessageBytes, beast::bind_front_handler(&WsSession::onRead, shared_from_this())); }

  void onRead(beast::error_code ec, size_t) {
    if (!mClient) return;  // closed meanwhile (a failed write, the queue's bound): what was read is dropped
    if (ec) {
      close(ec == websocket::error::message_too_big ? "sent a message over the limit" : "");
      return;
    }
    if (!mInMessage) {
      mInMessage = true;
      mDeadline.expires_after(mServer.options.messageTimeout);
      mDeadline.async_wait([self = shared_from_this()](beast::error_code e) {
        if (e || !self->mInMessage) return;
        self->close("took longer than the message timeout to send a message");
      });
    }
    if (!mWs.is_message_done()) {
      read();
      return;
    }
    mInMessage = false;
    mDeadline.cancel();
    if (!mWs.got_text()) {
      queue(errorMessage("message: expected JSON text, not binary"), false);
    } else {
      mServer.onMessage(mClient, beast::buffers_to_string(mBuffer.data()));
    }
    mBuffer.consume(mBuffer.size());
    if (mClient) read();
  }

  // Ends the session, once: the client leaves the server, what waits to be written is dropped and
  // the socket is closed, so that its pending read and write end with an error. A handler already
  // queued with a message read or a write done finds mClient empty and does nothing more.
  void close(const std::string& why = "") {
    if (!mClient) return;
    mServer.removeClient(mClient);
    mServer.log(why.empty() ? "client disconnected" : "client " + why + ": closed");
    mClient.reset();
    mDeadline.cancel();
    mQueue.erase(mQueue.begin() + (mWriting ? 1 : 0), mQueue.end());  // (the one being written is its buffer until the write ends)
    mWaitingTextBytes = 0;
    beast::get_lowest_layer(mWs).close();
  }

  // Text messages all go, up to kMaxQueuedTextBytes waiting (a client that does not read them is
  // closed); of frames only the newest waiting one (a slow link drops stale frames).
  void queue(std::string message, bool binary) {
    if (!mClient) return;
    if (binary) {
      for (auto it = mQueue.begin() + (mWriting ? 1 : 0); it != mQueue.end();)
        it = it->second ? mQueue.erase(it) : it + 1;
    } else if ((mWaitingTextBytes += message.size()) > kMaxQueuedTextBytes) {
      close("does not read its messages (over " + std::to_string(kMaxQueuedTextBytes) + " bytes waiting)");
      return;
    }
    mQueue.emplace_back(std::move(message), binary);
    if (!mWriting) write();
  }

  void write() {
    mWriting = true;
    const auto& [message, binary] = mQueue.front();
    if (!binary) mWaitingTextBytes -= message.size();
    mWs.binary(binary);
    mWs.async_write(net::buffer(message), beast::bind_front_handler(&WsSession::onWrite, shared_from_this()));
  }

  void onWrite(beast::error_code ec, size_t) {
    mQueue.pop_front();
    mWriting = false;
    if (!mClient) return;
    if (ec) {
      close();
      return;
    }
    if (!mQueue.empty()) write();
  }

  websocket::stream<beast::tcp_stream> mWs;
  ServerState& mServer;
  beast::flat_buffer mBuffer;
  net::steady_timer mDeadline{mWs.get_executor()};  // the message being read must be complete by then
  bool mInMessage = false;
  std::shared_ptr<Client> mClient;
  std::deque<std::pair<std::string, bool>> mQueue;  // messages to write, the front one being written while mWriting
  bool mWriting = false;
  size_t mWaitingTextBytes = 0;  // text messages in mQueue not being written yet
};

// An HTTP reply: its status, content type and body, and the headers some replies add.
struct Reply {
  http::status status = http::status::ok;
  std::string type, body;
  bool setCookie = false;  // the access token's cookie (the page opened with ?token=)
  bool headOnly = false;   // a HEAD request: the headers only
  std::string download;    // a file to save: its name (Content-Disposition)
};

// A plain-text reply: a refusal, or why a request failed.
Reply textReply(http::status status, std::string text) { return Reply{status, "text/plain", std::move(text), false, false, ""}; }

// One HTTP connection: the page's assets, the mesh export, or the upgrade to the WebSocket.
class HttpSession : public std::enable_shared_from_this<HttpSession> {
 public:
  HttpSession(tcp::socket&& socket, ServerState& server) : mStream(std::move(socket)), mServer(server) {}
  void run() { read(); }

 private:
  void read() {
    mParser.emplace();
    mParser->header_limit(8 * 1024);
    mParser->body_limit(1024);
    mStream.expires_after(std::chrono::seconds(30));
    http::async_read(mStream, mBuffer, *mParser, beast::bind_front_handler(&HttpSession::onRead, shared_from_this()));
  }

  void onRead(beast::error_code ec, size_t) {
    if (ec) {
      if (ec != http::error::end_of_stream && ec != beast::error::timeout && ec != net::error::operation_aborted) {
        // A malformed request: answer once and close.
        respond(textReply(http::status::bad_request, "bad request\n"), false, 11);
      }
      return;
    }
    http::request<http::string_body> req = mParser->release();
    const std::string target(req.target());
    const std::string path(targetPath(target));
    if (!authorised(req, mServer.token)) {
      respond(textReply(http::status::forbidden, "403: this page needs its access token (the URL hybrid-octree view printed)\n"), false, req.version());
      return;
    }
    if (websocket::is_upgrade(req)) {
      // Only this server's page may drive the viewer with the cookie it holds: browsers send the
      // page's origin with a socket; one without (not a browser's page) or of another is refused.
      const auto origin = req.find(http::field::origin);
      const auto host = req.find(http::field::host);
      if (path != "/ws" || origin == req.end() || host == req.end() || std::string(origin->value()) != "http://" + std::string(host->value())) {
        respond(textReply(http::status::forbidden, "403: not this page's socket\n"), false, req.version());
        return;
      }
      std::make_shared<WsSession>(mStream.release_socket(), mServer)->run(std::move(req));
      return;
    }
    if (req.method() != http::verb::get && req.method() != http::verb::head) {
      respond(textReply(http::status::method_not_allowed, "405: only GET\n"), req.keep_alive(), req.version());
      return;
    }
    const bool setCookie = queryParam(target, "token").has_value();
    if (path == "/api/mesh") {
      exportMesh(target, req.version(), req.keep_alive());
      return;
    }
    const Asset* asset = findAsset(path);
    if (!asset) {
      respond(textReply(http::status::not_found, "404: no such page\n"), req.keep_alive(), req.version());
      return;
    }
    respond(Reply{http::status::ok, std::string(asset->contentType), std::string(asset->bytes), setCookie, req.method() == http::verb::head, ""},
            req.keep_alive(), req.version());
  }

  void exportMesh(const std::string& target, unsigned version, bool keepAlive) {
    const auto iso = queryParam(target, "iso");
    const auto format = queryParam(target, "format").value_or("ply");
    std::string scene = queryParam(target, "scene").value_or(mServer.defaultScene);
    double value = 0;
    try {
      size_t used = 0;
      value = iso ? std::stod(*iso, &used) : NAN;
      if (!iso || used != iso->size() || !std::isfinite(value)) throw std::invalid_argument("iso");
    } catch (const std::exception&) {
      respond(textReply(http::status::bad_request, "400: iso: expected a number\n"), keepAlive, version);
      return;
    }
    if (!meshFormatOf("surface." + format)) {
      respond(textReply(http::status::bad_request, "400: format: expected " + meshExtensionsText(false, false) + "\n"), keepAlive, version);
      return;
    }
    auto self = shared_from_this();
    net::any_io_executor executor = mStream.get_executor();
    std::ostringstream name;  // the file's name says its isovalue
    name << "surface-" << float(value) << "." << format;
    mServer.queueExport(ExportJob{scene, float(value), format, [self, executor, version, keepAlive, file = name.str()](std::string body, std::string error) {
      net::post(executor, [self, body = std::move(body), error = std::move(error), version, keepAlive, file]() {
        if (!error.empty()) self->respond(textReply(http::status::bad_request, "400: " + error + "\n"), keepAlive, version);
        else self->respond(Reply{http::status::ok, "application/octet-stream", body, false, false, file}, keepAlive, version);
      });
    }});
  }

  void respond(Reply reply, bool keepAlive, unsigned version) {
    auto res = std::make_shared<http::response<http::string_body>>(reply.status, version);
    res->set(http::field::server, "hybrid-octree");
    res->set(http::field::content_type, reply.type);
    res->set(http::field::cache_control, "no-store");
    res->set("X-Content-Type-Options", "nosniff");
    res->set("Content-Security-Policy", "default-src 'self'; img-src 'self' blob: data:; connect-src 'self'");
    if (reply.setCookie) res->set(http::field::set_cookie, "hyb_token=" + mServer.token + "; Path=/; HttpOnly; SameSite=Strict");
    if (!reply.download.empty()) res->set(http::field::content_disposition, "attachment; filename=\"" + reply.download + "\"");
    res->keep_alive(keepAlive);
    const size_t size = reply.body.size();
    if (!reply.headOnly) res->body() = std::move(reply.body);
    res->content_length(size);
    http::async_write(mStream, *res, [self = shared_from_this(), res, keepAlive](beast::error_code ec, size_t) {
      if (ec || !keepAlive) {
        beast::error_code ignored;
        self->mStream.socket().shutdown(tcp::socket::shutdown_send, ignored);
        return;
      }
      self->read();
    });
  }

  beast::tcp_stream mStream;
  ServerState& mServer;
  beast::flat_buffer mBuffer;
  std::optional<http::request_parser<http::string_body>> mParser;
};

}  // namespace

void acceptConnections(ServerState& s) {
  s.acceptor.async_accept(net::make_strand(s.io), [&s](beast::error_code ec, tcp::socket socket) {
    if (ec) {
      if (!s.stopping) acceptConnections(s);
      return;
    }
    // Frames go out as written: Nagle's algorithm would hold a frame's last segment for the
    // client's delayed acknowledgement.
    beast::error_code ignored;
    socket.set_option(tcp::no_delay(true), ignored);
    std::make_shared<HttpSession>(std::move(socket), s)->run();
    acceptConnections(s);
  });
}

}  // namespace hyb::viewer
