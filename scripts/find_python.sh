#!/usr/bin/env sh
# Prints the interpreter `make` builds .venv with: the first Python 3.12 or 3.13 found on PATH or under
# pyenv's versions (pyenv's shims answer only for the selected version), else plain python3. Python 3.12+
# is where JAX >= 0.12 installs, whose CPU runtime runs a program sharded over several host devices.
for p in python3.12 python3.13 \
         "$(pyenv root 2>/dev/null)"/versions/3.12*/bin/python3.12 \
         "$(pyenv root 2>/dev/null)"/versions/3.13*/bin/python3.13 python3; do
  if "$p" -c 'import sys; sys.exit(sys.version_info < (3, 12))' 2>/dev/null; then
    command -v "$p" 2>/dev/null || echo "$p"; exit 0
  fi
done
echo python3
