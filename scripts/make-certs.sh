#!/usr/bin/env bash
# Make a private CA and one certificate per zenoh participant for rig-gateway's secure setup (docs/security.md).
#
#   scripts/make-certs.sh OUT_DIR NAME [NAME ...]
#
# OUT_DIR/ca.pem + ca-key.pem: the CA (keep ca-key.pem offline: whoever has it can mint devices).
# OUT_DIR/NAME/cert.pem + key.pem for each NAME (e.g. gateway rod-1 hook-1 ball-1): EC P-256, CN = NAME, valid for
# server and client auth, SAN localhost / 127.0.0.1 / NAME (so the gateway's certificate also works as the TLS
# server's). The zenoh access control matches a link's subject by this CN (cert_common_names).
# Existing files are kept, so adding a device later re-uses the CA. Private keys are 0600 in 0700 folders.
set -euo pipefail
if [ $# -lt 2 ]; then
  echo "usage: $0 OUT_DIR NAME [NAME ...]" >&2
  exit 2
fi
out=$1
shift
days=${CERT_DAYS:-825}
umask 077
mkdir -p "$out"
if [ ! -f "$out/ca.pem" ]; then
  openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$out/ca-key.pem"
  openssl req -x509 -new -key "$out/ca-key.pem" -sha256 -days "$days" -subj "/CN=rig-gateway CA" \
    -addext "basicConstraints=critical,CA:TRUE" -addext "keyUsage=critical,keyCertSign,cRLSign" \
    -out "$out/ca.pem"
fi
for name in "$@"; do
  case "$name" in
    *[!A-Za-z0-9_-]*|"") echo "bad name '$name' (A-Z a-z 0-9 _ - only)" >&2; exit 2 ;;
  esac
  dir="$out/$name"
  [ -f "$dir/cert.pem" ] && continue
  mkdir -p "$dir"
  openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$dir/key.pem"
  openssl req -new -key "$dir/key.pem" -subj "/CN=$name" -out "$dir/req.csr"
  ext=$(mktemp)
  printf '%s\n' "basicConstraints=critical,CA:FALSE" "keyUsage=critical,digitalSignature" \
    "extendedKeyUsage=serverAuth,clientAuth" "subjectAltName=DNS:localhost,IP:127.0.0.1,DNS:$name" > "$ext"
  openssl x509 -req -in "$dir/req.csr" -CA "$out/ca.pem" -CAkey "$out/ca-key.pem" -CAcreateserial \
    -days "$days" -sha256 -extfile "$ext" -out "$dir/cert.pem" 2>/dev/null
  rm -f "$ext" "$dir/req.csr"
done
chmod 644 "$out/ca.pem"
echo "certificates in $out: ca.pem and $(printf '%s/ ' "$@")"
