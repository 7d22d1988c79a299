#!/usr/bin/env bash
# Fails when a tracked file holds a private key: PEM (a BEGIN ... PRIVATE KEY line), DER (a
# PKCS#8, PKCS#1 RSA or SEC1 EC key: a SEQUENCE starting with a version INTEGER, where a
# certificate starts with a SEQUENCE in a SEQUENCE), or a key store by its name (.p12, .pfx,
# .pk8, .key). Keys are made where the software runs (docs/opcua.md), never committed.
#   .ci/check-no-keys.sh [REPO]     (default: this repository)
set -euo pipefail
repo="${1:-$(dirname "$0")/..}"
cd "$repo"
found=0
# PEM: the line of any private key, encrypted or not, whatever its algorithm.
while IFS= read -r f; do
  echo "private key (PEM) in tracked file $f" >&2
  found=1
done < <(git grep -lIE -- '-----BEGIN ([A-Z0-9]+ )*PRIVATE KEY-----' || true)
# DER and key stores: by their first bytes and names.
while IFS= read -r -d '' f; do
  [[ -f "$f" ]] || continue
  case "$f" in
    *.p12 | *.pfx | *.pk8 | *.key)
      echo "key store in tracked file $f" >&2
      found=1
      continue
      ;;
  esac
  head8=$(head -c 8 -- "$f" | od -An -tx1 | tr -d ' \n')
  case "$head8" in
    # SEQUENCE (long length) + INTEGER 0: PKCS#8 or PKCS#1 RSA private key.
    3082????020100*) ;&
    # SEQUENCE (short length) + INTEGER 1 + OCTET STRING: SEC1 EC private key.
    30??02010104*)
      echo "private key (DER) in tracked file $f" >&2
      found=1
      ;;
  esac
done < <(git ls-files -z)
if [[ $found -ne 0 ]]; then
  echo "remove the key from the index (git rm --cached FILE) and make it where it is used" >&2
  exit 1
fi
echo "no private key in the tracked files"
