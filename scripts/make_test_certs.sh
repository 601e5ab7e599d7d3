#!/usr/bin/env bash
# Generate a throw-away test CA and router/client certificates for Zenoh TLS (docs/bus.md).
#
#   scripts/make_test_certs.sh [OUT_DIR]      (default: ./certs)
#
# Writes ca.pem/ca.key, router.pem/router.key (SAN: localhost, 127.0.0.1, ::1) and
# client.pem/client.key (CN=qlap-client, for mutual TLS). Keys are RSA 2048, PKCS#8, valid for
# 30 days. For tests and examples only: never use these for anything that matters.
set -euo pipefail
OUT="${1:-certs}"
DAYS="${QLAP_CERT_DAYS:-30}"
mkdir -p "$OUT"
cd "$OUT"
umask 077

openssl req -x509 -newkey rsa:2048 -nodes -days "$DAYS" -sha256 \
  -keyout ca.key -out ca.pem -subj "/CN=qlap-test-ca" \
  -addext "basicConstraints=critical,CA:TRUE" -addext "keyUsage=critical,keyCertSign,cRLSign" \
  2>/dev/null

issue() {  # issue NAME CN SAN EKU
  local name="$1" cn="$2" san="$3" eku="$4"
  openssl req -newkey rsa:2048 -nodes -keyout "$name.key" -out "$name.csr" -subj "/CN=$cn" \
    2>/dev/null
  printf 'basicConstraints=CA:FALSE\nkeyUsage=critical,digitalSignature,keyEncipherment\n%s\n%s\n' \
    "extendedKeyUsage=$eku" "subjectAltName=$san" > "$name.ext"
  openssl x509 -req -in "$name.csr" -CA ca.pem -CAkey ca.key -CAcreateserial -days "$DAYS" \
    -sha256 -extfile "$name.ext" -out "$name.pem" 2>/dev/null
  rm -f "$name.csr" "$name.ext"
}

issue router localhost "DNS:localhost,IP:127.0.0.1,IP:::1" serverAuth,clientAuth
issue client qlap-client "DNS:qlap-client" clientAuth
rm -f ca.srl
chmod 644 ./*.pem
echo "wrote $(pwd)/{ca,router,client}.{pem,key}"
