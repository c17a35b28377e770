#!/usr/bin/env bash
# Issue a site's certificates for the locked-down zenoh router (router.json5, client.json5):
# a CA, the router's certificate, and one certificate per role, whose common name is the role
# the router's access control checks (dlo-camera, dlo-service, dlo-robot, dlo-dashboard).
#
#   make-certs.sh OUT_DIR [ROUTER_NAME ...]
#
# ROUTER_NAME: the host names clients use to reach the router (default: router localhost),
# written into its certificate; 127.0.0.1 is always included. Keys are ECDSA P-256, valid for
# DAYS days (default 825). Keep ca-key.pem offline; give each device only ca.pem and its own
# role's pair. Needs openssl.
set -euo pipefail
out=${1:?usage: make-certs.sh OUT_DIR [ROUTER_NAME ...]}
shift
if [[ $# -eq 0 ]]; then names=(router localhost); else names=("$@"); fi
days=${DAYS:-825}
mkdir -p "$out"
cd "$out"

key() { openssl ecparam -name prime256v1 -genkey -noout | openssl pkcs8 -topk8 -nocrypt -out "$1"; }

key ca-key.pem
openssl req -x509 -new -key ca-key.pem -sha256 -days "$days" -subj "/CN=dlo site CA" \
  -addext "basicConstraints=critical,CA:TRUE" -addext "keyUsage=critical,keyCertSign,cRLSign" \
  -out ca.pem 2>/dev/null

issue() {  # issue NAME CN SUBJECT_ALT_NAMES
  key "$1-key.pem"
  openssl req -new -key "$1-key.pem" -subj "/CN=$2" -out "$1.csr" 2>/dev/null
  printf 'basicConstraints=CA:FALSE\nkeyUsage=critical,digitalSignature\nextendedKeyUsage=serverAuth,clientAuth\nsubjectAltName=%s\n' "$3" > "$1.ext"
  openssl x509 -req -in "$1.csr" -CA ca.pem -CAkey ca-key.pem -CAcreateserial -days "$days" \
    -sha256 -extfile "$1.ext" -out "$1.pem" 2>/dev/null
  rm -f "$1.csr" "$1.ext"
}

sans="IP:127.0.0.1"
for name in "${names[@]}"; do sans="$sans,DNS:$name"; done
issue router dlo-router "$sans"
for role in camera service robot dashboard; do
  issue "$role" "dlo-$role" "DNS:dlo-$role"
done
rm -f ca.srl
chmod 600 ./*-key.pem
echo "certificates in $out: ca.pem, router.pem, camera.pem, service.pem, robot.pem, dashboard.pem (+ *-key.pem)" >&2
