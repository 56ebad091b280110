#!/bin/sh
# A master from outside Python for the drill's tests: mbpoll (libmodbus) in a shell loop.
#   mbpoll_master.sh [one] tcp HOST PORT      Modbus TCP
#   mbpoll_master.sh [one] rtu PTY            Modbus RTU on a serial port (19200 8N1)
# Writes 2001H = 1500 and 2000H = 1 once, then every 100 ms reads 2100H and 3006H (with `one`: 2100H alone, one
# request polled), one attempt each with a 250 ms timeout (no retry), and acts on nothing it reads.
set -u
registers="0x2100 0x3006"
if [ "$1" = one ]; then
    registers="0x2100"
    shift
fi
if [ "$1" = tcp ]; then
    link="-m tcp -p $3 $2"
else
    link="-m rtu -b 19200 -P none $2"
fi
poll() { mbpoll -a 1 -0 -o 0.25 "$@" > /dev/null 2>&1; }
# shellcheck disable=SC2086
poll -r 0x2001 $link 1500
# shellcheck disable=SC2086
poll -r 0x2000 $link 1
while :; do
    for register in $registers; do
        # shellcheck disable=SC2086
        poll -t 4 -r "$register" -c 1 -1 $link
    done
    sleep 0.1
done
