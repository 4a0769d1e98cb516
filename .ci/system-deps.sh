#!/usr/bin/env bash
# Installs the Debian packages the renderer, the farm tests and the browser tests use, when we may.
# Without root or apt, says which command to run instead and carries on.
set -u
need=()
for lib in libEGL.so.1 libGL.so.1; do
  ldconfig -p 2>/dev/null | grep -q "$lib" || need+=("$lib")
done
ls /usr/lib/*/dri/swrast_dri.so /usr/lib/*/dri/*_dri.so >/dev/null 2>&1 || need+=(mesa-dri)
command -v redis-server >/dev/null 2>&1 || need+=(redis-server)
[ -x /usr/bin/chromium ] || need+=(chromium)  # the dailies page's browser tests (Playwright)
[ ${#need[@]} -eq 0 ] && exit 0
pkgs="libegl1 libegl-mesa0 libgl1-mesa-dri redis-server chromium"
if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
  echo "installing system packages: $pkgs" >&2
  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $pkgs) >&2 || \
    echo "warning: apt-get install failed; run: apt-get install -y $pkgs" >&2
else
  echo "missing ${need[*]}; run as root: apt-get install -y $pkgs" >&2
fi
exit 0
