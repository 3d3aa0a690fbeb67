#!/bin/sh
# The password comes from the environment (POSTGRES_PASSWORD), never from the image.
set -eu
umask 077
printf '"attune" "%s"\n' "${POSTGRES_PASSWORD:?set POSTGRES_PASSWORD}" > /tmp/userlist.txt
exec pgbouncer /etc/pgbouncer/pgbouncer.ini
