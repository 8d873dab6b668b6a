#!/usr/bin/env bash
# Makes a home's certificate authority and the certificates its PLANET endpoints present
# (docs/security.md): the mediating server's, and one client certificate per device manager or
# agent name given. Keys are EC P-256; certificates are valid for 10 years.
#
#   scripts/make-certs.sh DIR [--server-name NAME]... [--client NAME]...
#
# DIR/ca.pem, DIR/ca.key          the home's CA (keep ca.key off the devices)
# DIR/server.pem, DIR/server.key  CN icars-server; SANs: localhost, 127.0.0.1, ::1, --server-name
# DIR/<client>.pem, .key          CN <client>, for mutual TLS (Principal "certificate")
# An existing CA in DIR is reused, so more clients can be added later.
set -euo pipefail

if [ $# -lt 1 ] || [[ "$1" == -* ]]; then
  echo "usage: $0 DIR [--server-name NAME]... [--client NAME]..." >&2
  exit 2
fi
dir=$1
shift
sans="DNS:localhost,IP:127.0.0.1,IP:::1"
clients=()
while [ $# -gt 0 ]; do
  case "$1" in
    --server-name)
      [ $# -ge 2 ] || { echo "$0: --server-name needs a value" >&2; exit 2; }
      if [[ "$2" =~ ^[0-9.]+$ || "$2" == *:* ]]; then sans+=",IP:$2"; else sans+=",DNS:$2"; fi
      shift 2 ;;
    --client)
      [ $# -ge 2 ] || { echo "$0: --client needs a value" >&2; exit 2; }
      [[ "$2" =~ ^[A-Za-z0-9._-]+$ ]] || { echo "$0: client name '$2': use letters, digits, . _ -" >&2; exit 2; }
      clients+=("$2")
      shift 2 ;;
    *) echo "$0: unknown argument '$1'" >&2; exit 2 ;;
  esac
done

command -v openssl >/dev/null || { echo "$0: needs the openssl command (apt-get install openssl)" >&2; exit 1; }
mkdir -p "$dir"
umask 077

key() { openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$1" 2>/dev/null; }

if [ ! -f "$dir/ca.pem" ]; then
  key "$dir/ca.key"
  openssl req -x509 -new -key "$dir/ca.key" -subj "/CN=ICARS home CA" -days 3650 -sha256 \
    -addext "basicConstraints=critical,CA:TRUE" -addext "keyUsage=critical,keyCertSign,cRLSign" \
    -out "$dir/ca.pem" 2>/dev/null
fi

# sign NAME CN EXTENSIONS
sign() {
  local name=$1 cn=$2 ext=$3
  key "$dir/$name.key"
  openssl req -new -key "$dir/$name.key" -subj "/CN=$cn" -out "$dir/$name.csr" 2>/dev/null
  openssl x509 -req -in "$dir/$name.csr" -CA "$dir/ca.pem" -CAkey "$dir/ca.key" -CAcreateserial \
    -days 3650 -sha256 -extfile <(printf '%s\n' "$ext") -out "$dir/$name.pem" 2>/dev/null
  rm -f "$dir/$name.csr"
}

# A server's certificate is a client's too: the servers of one logical mediating server
# (icars serve --peer) present it on the links they open to each other.
sign server icars-server "subjectAltName=$sans
extendedKeyUsage=serverAuth,clientAuth
basicConstraints=CA:FALSE"
for c in "${clients[@]}"; do
  sign "$c" "$c" "extendedKeyUsage=clientAuth
basicConstraints=CA:FALSE"
done
chmod 644 "$dir"/*.pem
echo "make-certs: CA, server and ${#clients[@]} client certificate(s) in $dir"
