"""The Dynamixel emulator's instruction handling: one parsed packet -> the servos' answers and effects (ping,
read, write, reboot, factory reset, sync / fast sync / bulk reads, sync writes, goal current to the bank).

SIMULATED DEVICE. A mixin of DynamixelEmulator (emulator.py: the transport, pty thread or in process, and
the servos' state refreshed from the bank); the attributes are the emulator's.
"""

from __future__ import annotations

import numpy as np

from hardware.dynamixel import protocol as p
from hardware.dynamixel import watchdog as wd
from hardware.dynamixel.fast_sync import FAST_SYNC_READ_MIN_FIRMWARE, build_fast_status
from hardware.dynamixel.servo_table import ServoTable


class EmulatorInstructions:
    """Protocol 2.0 instructions as the X-series firmware executes them (mixed into DynamixelEmulator)."""

    def _handle(self, pkt: p.Packet) -> None:
        if pkt.is_status:
            return  # another device's reply on the bus
        self.instructions += 1
        if self.drop_prob > 0 and self._rng.random() < self.drop_prob:
            self.dropped += 1
            return
        if self._wd_armed:
            self._watchdog_rx()
        inst, prm = pkt.instruction, pkt.params
        if inst == p.INST_SYNC_READ or inst == p.INST_BULK_READ:
            self._chain_read(inst, prm)
            return
        if inst == p.INST_SYNC_WRITE:
            self._sync_write(prm)
            return
        if inst == p.INST_FAST_SYNC_READ:
            self._fast_sync_read(prm)
            return
        for s in self._live(pkt.id):
            err, data = self._execute(s, inst, prm)
            if err is None:
                continue
            level = s.get(p.ADDR_STATUS_RETURN_LEVEL)
            if pkt.id == p.BROADCAST_ID and inst != p.INST_PING:
                continue
            if inst == p.INST_PING or level == 2 or (level == 1 and inst == p.INST_READ):
                self._send(s, p.build_status(s.id, err | s.alert, data))

    def _execute(self, s: ServoTable, inst: int, prm: bytes) -> tuple[int | None, bytes]:
        if inst == p.INST_PING:
            return p.ERR_NONE, p.le(s.model.model_number, 2) + bytes([s.table[p.ADDR_FIRMWARE_VERSION[0]]])
        if inst == p.INST_READ:
            if len(prm) != 4:
                return p.ERR_DATA_LENGTH, b""
            a, n = p.from_le(prm[:2]), p.from_le(prm[2:])
            if a + n > p.CONTROL_TABLE_SIZE:
                return p.ERR_DATA_RANGE, b""
            self._refresh([s])
            return p.ERR_NONE, bytes(s.table[a : a + n])
        if inst == p.INST_WRITE:
            if len(prm) < 3:
                return p.ERR_DATA_LENGTH, b""
            return self._write(s, p.from_le(prm[:2]), prm[2:]), b""
        if inst == p.INST_REBOOT:
            self._write(s, p.ADDR_TORQUE_ENABLE[0], b"\x00")
            s.table[p.ADDR_HARDWARE_ERROR_STATUS[0]] = 0
            s.table[wd.ADDR[0]] = 0  # RAM back to its defaults: the watchdog off, its error cleared
            s.watchdog.latched = False
            self._watchdog_rearm_state()
            s.turn_base = None
            self._refresh([s])
            return p.ERR_NONE, b""
        return p.ERR_INSTRUCTION, b""

    def _write(self, s: ServoTable, addr: int, data: bytes) -> int:
        """Apply a write to the control table and the bank; returns the status error code."""
        err = s.check_write(addr, data)
        if err:
            return err
        torque_before = s.torque_on
        s.store(addr, data)
        if addr <= wd.ADDR[0] < addr + len(data) or addr <= p.ADDR_TORQUE_ENABLE[0] < addr + len(data):
            self._watchdog_written(s)
        self._apply(s, torque_before, addr, addr + len(data))
        return p.ERR_NONE

    def _apply(self, s: ServoTable, torque_before: bool, addr: int, end: int) -> None:
        idx = np.array([s.index])
        mode = s.table[p.ADDR_OPERATING_MODE[0]]
        touched = range(addr, end).__contains__
        with self._bank_lock:
            if not s.torque_on:
                if torque_before or touched(p.ADDR_TORQUE_ENABLE[0]):
                    self.bank.enable(idx, False)
                return
            if mode == p.OP_MODE_CURRENT and (not torque_before or touched(p.ADDR_GOAL_CURRENT[0])):
                amps = s.get(p.ADDR_GOAL_CURRENT, signed=True) * s.model.amps_per_unit
                if self._pending_current is not None:  # inside a sync write: one bank call for all servos
                    self._pending_current.append((s.index, s.sign * amps))
                else:
                    self.bank.command_current(idx, np.array([s.sign * amps]))
            elif mode in (p.OP_MODE_POSITION, p.OP_MODE_EXTENDED_POSITION, p.OP_MODE_CURRENT_BASED_POSITION):
                if not torque_before:  # torque on: hold where it is (goal := present)
                    s.table[p.ADDR_GOAL_POSITION[0] : p.ADDR_GOAL_POSITION[0] + 4] = s.table[
                        p.ADDR_PRESENT_POSITION[0] : p.ADDR_PRESENT_POSITION[0] + 4
                    ]
                if not torque_before or touched(p.ADDR_GOAL_POSITION[0]):
                    q = s.joint_angle(s.get(p.ADDR_GOAL_POSITION, signed=True))
                    self.bank.command_position(idx, np.array([q]))
            elif not torque_before:
                self.bank.command_current(idx, np.zeros(1))  # velocity/PWM modes: not modelled, no torque

    def _chain_read(self, inst: int, prm: bytes) -> None:
        """Sync read (addr, len, ids...) or bulk read ((id, addr, len)*): listed servos answer in order."""
        if inst == p.INST_SYNC_READ:
            if len(prm) < 5:
                return
            a, n = p.from_le(prm[:2]), p.from_le(prm[2:4])
            plan = [(i, a, n) for i in prm[4:]]
        else:
            if len(prm) % 5:
                return
            plan = [
                (prm[k], p.from_le(prm[k + 1 : k + 3]), p.from_le(prm[k + 3 : k + 5]))
                for k in range(0, len(prm), 5)
            ]
        live = {s.id: s for s in self._live(p.BROADCAST_ID)}
        targets = [(live[i], a, n) for i, a, n in plan if i in live]
        if not targets:
            return
        self._refresh([t[0] for t in targets])
        replies = [
            p.build_status(s.id, p.ERR_DATA_RANGE | s.alert)
            if a + n > p.CONTROL_TABLE_SIZE
            else p.build_status(s.id, s.alert, bytes(s.table[a : a + n]))
            for s, a, n in targets
        ]
        delays = self.emulate_return_delay and any(s.get(p.ADDR_RETURN_DELAY_TIME) for s, _, _ in targets)
        if not delays:  # one write for the whole chain: what the wire would deliver back to back
            self._send(targets[0][0], b"".join(replies))
            return
        for (s, _, _), r in zip(targets, replies):  # each answers after the previous, its return delay apart
            self._send(s, r)

    def _fast_sync_read(self, prm: bytes) -> None:
        """Fast sync read (addr, len, ids...): one packet for the chain (hardware.dynamixel.fast_sync); a
        listed servo that is silent or whose firmware predates the instruction leaves its slot empty."""
        if len(prm) < 5:
            return
        a, n = p.from_le(prm[:2]), p.from_le(prm[2:4])
        live = {s.id: s for s in self._live(p.BROADCAST_ID)}
        fw = p.ADDR_FIRMWARE_VERSION[0]
        targets = [live.get(i) for i in prm[4:]]
        targets = [s if s and s.table[fw] >= FAST_SYNC_READ_MIN_FIRMWARE else None for s in targets]
        present = [s for s in targets if s is not None]
        if not present:
            return
        self._refresh(present)
        blocks = [
            None if s is None
            else (s.id, p.ERR_DATA_RANGE | s.alert, b"") if a + n > p.CONTROL_TABLE_SIZE
            else (s.id, s.alert, bytes(s.table[a : a + n]))
            for s in targets
        ]
        self._send(present[0], build_fast_status(blocks, n))

    def _sync_write(self, prm: bytes) -> None:
        if len(prm) < 4:
            return
        a, n = p.from_le(prm[:2]), p.from_le(prm[2:4])
        body = prm[4:]
        if n == 0 or len(body) % (n + 1):
            return
        live = {s.id: s for s in self._live(p.BROADCAST_ID)}
        if (a, n) == p.ADDR_GOAL_CURRENT:
            self._sync_write_goal_current(live, body)
            return
        self._pending_current = []
        try:
            for k in range(0, len(body), n + 1):
                s = live.get(body[k])
                if s is not None:
                    self._write(s, a, bytes(body[k + 1 : k + 1 + n]))
            pend = self._pending_current
        finally:
            self._pending_current = None
        if pend:
            with self._bank_lock:
                self.bank.command_current(np.array([i for i, _ in pend]), np.array([c for _, c in pend]))

    def _sync_write_goal_current(self, live: dict[int, ServoTable], body: bytes) -> None:
        """The per-tick sync write, without the generic path's per-servo checks (same rules: RAM address,
        range-checked against Current Limit(38), applied only with torque on in current mode)."""
        g, lim = p.ADDR_GOAL_CURRENT[0], p.ADDR_CURRENT_LIMIT[0]
        idx, amps = [], []
        for k in range(0, len(body), 3):
            s = live.get(body[k])
            if s is None:
                continue
            if s.watchdog.latched:
                continue  # Bus Watchdog Error: goals are read-only (a sync write has no status to say so)
            t, raw = s.table, body[k + 1 : k + 3]
            v = int.from_bytes(raw, "little", signed=True)
            if abs(v) > t[lim] | (t[lim + 1] << 8):
                continue  # data range error; a sync write has no status to carry it
            t[g : g + 2] = raw
            if t[p.ADDR_TORQUE_ENABLE[0]] == 1 and t[p.ADDR_OPERATING_MODE[0]] == p.OP_MODE_CURRENT:
                idx.append(s.index)
                amps.append(s.sign * v * s.model.amps_per_unit)
        if idx:
            with self._bank_lock:
                self.bank.command_current(np.array(idx), np.array(amps))
