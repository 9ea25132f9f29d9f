#!/usr/bin/env bash
# make view: the default world, live in a browser.
#
# Starts Rerun's web viewer server on localhost (gRPC on VIEW_GRPC_PORT for the node, the
# viewer page on VIEW_WEB_PORT), runs the node streaming to it until Ctrl-C (or STEPS steps
# when STEPS > 0), and prints the address to open. Any way out stops both: the server gets
# SIGTERM from the trap (a background job of a script ignores the terminal's SIGINT).
set -euo pipefail
cd "$(dirname "$0")/.."
grpc_port=${VIEW_GRPC_PORT:-9876}
web_port=${VIEW_WEB_PORT:-9090}
steps=${STEPS:-0}
# The viewer binary itself: .venv/bin/rerun is a script that runs it as a child process,
# which a signal to the script would leave behind.
rerun_bin=$(.venv/bin/python -c 'import pathlib, rerun_cli; print(pathlib.Path(rerun_cli.__file__).parent / "rerun")')

for port in "$grpc_port" "$web_port"; do
  if (exec 3<>"/dev/tcp/127.0.0.1/$port") 2>/dev/null; then
    echo "view: port $port on 127.0.0.1 is taken (another viewer?); free it or set" \
         "VIEW_GRPC_PORT / VIEW_WEB_PORT" >&2
    exit 1
  fi
done

mkdir -p runs
# The server keeps what it relays for pages opened later, up to VIEW_SERVER_MEMORY; past it
# the oldest frames go (the walls, the balls' looks and the layout are kept: the node logs
# them static). A page opened an hour in gets the last few seconds, not the hour: a web
# viewer rendering in software takes in a backlog slowly, and shows nothing new meanwhile.
"$rerun_bin" --serve-web --bind 127.0.0.1 --port "$grpc_port" --web-viewer-port "$web_port" \
  --server-memory-limit "${VIEW_SERVER_MEMORY:-128KiB}" \
  --hide-welcome-screen > runs/rerun_server.log 2>&1 &
server=$!
stop_server() {
  if kill -0 "$server" 2>/dev/null; then
    kill -TERM "$server" 2>/dev/null || true
  fi
  wait "$server" 2>/dev/null || true
}
trap stop_server EXIT
trap 'exit 130' INT TERM

for _ in $(seq 100); do
  if (exec 3<>"/dev/tcp/127.0.0.1/$grpc_port") 2>/dev/null; then break; fi
  if ! kill -0 "$server" 2>/dev/null; then
    echo 'view: the Rerun server did not start; see runs/rerun_server.log' >&2
    exit 1
  fi
  sleep 0.1
done

proxy="rerun+http://127.0.0.1:$grpc_port/proxy"
echo
echo "  Open http://127.0.0.1:$web_port/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A$grpc_port%2Fproxy"
echo "  (the page takes a few seconds to load; Ctrl-C stops the world and the server)"
echo
# In the foreground, so Ctrl-C reaches the node, which closes cleanly; then the EXIT trap
# stops the server.
.venv/bin/ball_world --ros-args --params-file config/ball_world.yaml -p max_steps:="$steps" \
  -p view.rerun:="$proxy" -p rerun.trail_seconds:=1.0
