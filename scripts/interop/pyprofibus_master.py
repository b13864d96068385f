"""pyprofibus (GPL-2.0-or-later) as an independent PROFIBUS DP master for hartkit's
gateway: run as a separate process by crates/hartkit/tests/gateway_profibus.rs, never
imported or shipped by hartkit.

Usage: pyprofibus_master.py PORT GSD ADDRESS MODULES SECONDS [LOOPTEST_SLOT]
(the bit rate is 19200, or $PYPROFIBUS_BAUD)

Parameterises and configures the station at ADDRESS from the GSD file with MODULES
"HART device" modules, exchanges data for SECONDS, and prints one JSON line per
second: the input image (hex) and the diagnosis flags pyprofibus saw. With
LOOPTEST_SLOT, after 3 s of data exchange it writes fixed current 12.5 mA with write
counter 1 to that module.
"""
import json
import os
import struct
import sys
import tempfile
import time

import pyprofibus


def main():
    port, gsd, address, modules, seconds = sys.argv[1:6]
    address, modules, seconds = int(address), int(modules), float(seconds)
    looptest = int(sys.argv[6]) if len(sys.argv) > 6 else None
    conf = "\n".join([
        "[PROFIBUS]", "debug = 0",
        "[PHY]", "type = serial", "dev = " + port,
        "baud = " + os.environ.get("PYPROFIBUS_BAUD", "19200"),
        "[DP]", "master_class = 1", "master_addr = 2",
        "[SLAVE_0]", "name = hartkit", "addr = %d" % address, "gsd = " + gsd,
        "sync_mode = 0", "freeze_mode = 0", "group_mask = 1", "watchdog_ms = 2000",
        # pyprofibus names the sizes from the slave's side of the output image:
        # input_size is what the master sends (our outputs), output_size what the
        # slave returns (our inputs).
        "input_size = %d" % (6 * modules), "output_size = %d" % (28 * modules),
    ] + ["module_%d = HART device 28 in/6 out" % i for i in range(modules)]) + "\n"
    with tempfile.NamedTemporaryFile("w", suffix=".conf", delete=False) as f:
        f.write(conf)
        path = f.name
    try:
        config = pyprofibus.PbConf.fromFile(path)
    finally:
        os.unlink(path)
    master = config.makeDPM()
    slave = config.slaveConfs[0].makeDpSlaveDesc()
    master.addSlave(slave)
    out = bytearray(6 * modules)
    master.initialize()
    start = time.monotonic()
    exchanging_since = None
    last_print = 0.0
    last_in = None
    try:
        while time.monotonic() - start < seconds:
            handled = master.run()
            if handled is not None:
                data = handled.getMasterInData()
                if data is not None:
                    last_in = bytes(data)
                    if exchanging_since is None:
                        exchanging_since = time.monotonic()
                handled.setMasterOutData(bytes(out))
            now = time.monotonic()
            if (looptest is not None and exchanging_since is not None
                    and now - exchanging_since > 3 and out[6 * looptest] == 0):
                out[6 * looptest] = 1
                out[6 * looptest + 2:6 * looptest + 6] = struct.pack(">f", 12.5)
            if now - last_print >= 1.0:
                last_print = now
                print(json.dumps({
                    "t": round(now - start, 2),
                    "connected": bool(slave.isConnected()),
                    "inputs": last_in.hex() if last_in else None,
                }), flush=True)
    finally:
        master.destroy()


if __name__ == "__main__":
    main()
