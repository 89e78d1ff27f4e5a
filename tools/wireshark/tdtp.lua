-- Wireshark dissector for TDTP, the Teleoperation Data Transport Protocol, version 4
-- (docs/PROTOCOL.md in the tdtp repository).
--
-- Load it for one run:   tshark -X lua_script:tools/wireshark/tdtp.lua -r capture.pcap
--                        wireshark -X lua_script:tools/wireshark/tdtp.lua capture.pcap
-- or for good: copy it into Wireshark's personal Lua plugins folder (Help > About > Folders).
--
-- What it decodes: the 5-byte base header (TYPE, SEQ, ACK, SACK, HOLD with the hold time in
-- microseconds, and which peer packets the ACK/SACK fields report received or absent), DATA
-- payloads, ACK padding, every CONTROL body (OPEN, OPEN_ACK, COOKIE, KEEPALIVE, CLOSE, REJECT, RESET,
-- PATH_CHALLENGE, PATH_RESPONSE, the reliable control channel's MESSAGE and MESSAGE_ACK, and the
-- multipath MP_CHALLENGE, MP_RESPONSE, MP_REPORT and MP_ABANDON, the send timestamps TIMESTAMP and
-- TIMED_DATA, and the rendezvous messages REGISTER, REFERRAL, PROBE and PROBE_ACK of a relay and
-- its pairs), and
-- the keyed layout (packet number, sealed body, authentication tag). It cannot decrypt or verify
-- a keyed session: the keys derive from a pre-shared key it does not have. Malformed packets get
-- expert info (Analyze > Expert Information; tshark: -z expert).
--
-- How it finds TDTP: TDTP has no port of its own (UDP 47000, which tdtp's examples use, belongs to
-- HCrt in Wireshark). A heuristic claims any UDP datagram that is a well-formed TDTP handshake
-- message (code, exact size, version 4; or a REGISTER or REFERRAL), and then every datagram of that
-- address pair (a relay's forwarded sessions included); a multipath session's further paths are
-- claimed by their MP_CHALLENGE (right size, HOLD 255), a punched path by its PROBE. For a
-- capture that starts mid-session, list the slave's port in the preference "tdtp.ports"
-- (tshark -o tdtp.ports:47000), or let heuristics run first (-o udp.try_heuristic_first:TRUE).
-- Whether a session is keyed is learnt from its OPEN or OPEN_ACK; preference "tdtp.keyed" forces it.

local tdtp = Proto("tdtp", "Teleoperation Data Transport Protocol")

local TYPE_NAMES = { [0] = "DATA", [1] = "ACK", [2] = "CONTROL", [3] = "reserved" }
local CODE_NAMES = {
    [1] = "OPEN", [2] = "OPEN_ACK", [3] = "KEEPALIVE", [4] = "CLOSE", [5] = "REJECT", [6] = "COOKIE",
    [7] = "RESET",
    [8] = "PATH_CHALLENGE", [9] = "PATH_RESPONSE",
    [10] = "MESSAGE", [11] = "MESSAGE_ACK",
    [15] = "TIMESTAMP", [16] = "TIMED_DATA",
    [17] = "MP_CHALLENGE", [18] = "MP_RESPONSE", [19] = "MP_REPORT", [20] = "MP_ABANDON",
    [21] = "REGISTER", [22] = "REFERRAL", [23] = "PROBE", [24] = "PROBE_ACK",
}
local REFERRAL_KINDS = {
    [0] = "COOKIE", [1] = "WAITING", [2] = "PEER", [3] = "REFUSED", [4] = "UNKNOWN", [5] = "LEFT",
}
local SUITE_NAMES = { [0] = "none", [1] = "AES-128-GCM", [2] = "ChaCha20-Poly1305" }
local REASON_NAMES = {
    [0] = "NORMAL", [1] = "IDLE_TIMEOUT", [2] = "PROTOCOL_ERROR", [3] = "VERSION_UNSUPPORTED",
    [4] = "REFUSED", [5] = "BUSY", [6] = "KEY_REQUIRED", [7] = "KEY_UNKNOWN",
    [8] = "PAYLOAD_TOO_SMALL", [9] = "SUITE_UNSUPPORTED", [10] = "REPLACED", [11] = "KEY_EXHAUSTED",
    [12] = "IN_USE", [13] = "TAKEN_OVER", [14] = "EVICTED", [15] = "RESTARTING",
    [19] = "PATH_CLOSED", [20] = "PATH_LIMIT", [21] = "ROLE_CONFLICT", [22] = "RENDEZVOUS_FULL",
}
local HOLD_NAMES = { [254] = "saturated (31.744 ms or more)", [255] = "no acknowledgement" }

local HEADER = 5
local PN = 2
local TAG = 16
local VERSION = 4
local RESET_ECHO = 16
-- MESSAGE: code, the master's nonce, seq, ack before the message; MESSAGE_ACK: code, nonce, ack.
local MESSAGE_PREFIX = 21
local MESSAGE_ACK = 19
-- TIMESTAMP: code, the sender's clock (u32, microseconds); TIMED_DATA: the same, then the sample.
local STAMP = 5
-- Bytes of a control datagram by code: unkeyed, keyed (nil: never protected).
local CONTROL_SIZES = {
    [1] = { 53, 69 }, [2] = { 45, 61 }, [3] = { 22, 40 }, [4] = { 23, 41 }, [5] = { 23 }, [6] = { 39 },
    [8] = { 22 }, [9] = { 38 }, [23] = { 38 }, [24] = { 38 },
    [17] = { 31, 49 }, [18] = { 39, 57 }, [19] = { 40, 58 }, [20] = { 24, 42 },
}

local f = tdtp.fields
f.type = ProtoField.uint8("tdtp.type", "Type", base.DEC, TYPE_NAMES, 0xC0)
f.seq = ProtoField.uint16("tdtp.seq", "SEQ", base.DEC_HEX, nil, 0x3FFC)
f.ack = ProtoField.uint24("tdtp.ack", "ACK", base.DEC_HEX, nil, 0x03FFC0)
f.sack = ProtoField.uint8("tdtp.sack", "SACK", base.HEX, nil, 0x3F)
f.hold = ProtoField.uint8("tdtp.hold", "HOLD code", base.DEC, HOLD_NAMES)
f.hold_us = ProtoField.uint32("tdtp.hold_us", "Hold (us)", base.DEC)
f.acked = ProtoField.uint16("tdtp.acked", "Reports received", base.DEC_HEX)
f.absent = ProtoField.uint16("tdtp.absent", "Reports absent", base.DEC_HEX)
f.payload = ProtoField.bytes("tdtp.payload", "Payload")
f.payload_len = ProtoField.uint16("tdtp.payload_len", "Payload length", base.DEC)
f.padding = ProtoField.bytes("tdtp.padding", "Padding")
f.code = ProtoField.uint8("tdtp.code", "Control code", base.DEC, CODE_NAMES)
f.version = ProtoField.uint8("tdtp.version", "Version", base.DEC)
f.flags = ProtoField.uint8("tdtp.flags", "Flags", base.HEX)
f.flag_separate = ProtoField.bool("tdtp.flags.separate_acks", "SEPARATE_ACKS", 8, nil, 0x01)
f.flag_keyed = ProtoField.bool("tdtp.flags.keyed", "KEYED", 8, nil, 0x02)
f.flag_encrypted = ProtoField.bool("tdtp.flags.encrypted", "ENCRYPTED", 8, nil, 0x04)
f.flag_takeover = ProtoField.bool("tdtp.flags.takeover", "TAKEOVER", 8, nil, 0x08)
f.flag_timestamps = ProtoField.bool("tdtp.flags.timestamps", "TIMESTAMPS", 8, nil, 0x20)
f.flag_multipath = ProtoField.bool("tdtp.flags.multipath", "MULTIPATH", 8, nil, 0x40)
f.flag_slave_dials = ProtoField.bool("tdtp.flags.slave_dials", "SLAVE_DIALS", 8, nil, 0x80)
f.flag_reserved = ProtoField.uint8("tdtp.flags.reserved", "Reserved", base.HEX, nil, 0x10)
f.rv_flags = ProtoField.uint8("tdtp.register.flags", "Register flags", base.HEX)
f.rv_listener = ProtoField.bool("tdtp.register.listener", "LISTENER", 8, nil, 0x01)
f.rv_leave = ProtoField.bool("tdtp.register.leave", "LEAVE", 8, nil, 0x02)
f.rv_id = ProtoField.bytes("tdtp.rendezvous_id", "Rendezvous id")
f.rv_kind = ProtoField.uint8("tdtp.referral.kind", "Referral kind", base.DEC, REFERRAL_KINDS)
f.rv_lifetime = ProtoField.uint16("tdtp.referral.lifetime", "Lifetime (s)", base.DEC)
f.rv_address = ProtoField.string("tdtp.rendezvous.address", "Address")
f.rv_token = ProtoField.bytes("tdtp.probe.token", "Probe token")
f.rv_mac = ProtoField.bytes("tdtp.probe.mac", "Probe MAC (under the pair's probe key)")
f.suite = ProtoField.uint8("tdtp.suite", "Cipher suite", base.DEC, SUITE_NAMES)
f.max_payload = ProtoField.uint16("tdtp.max_payload", "Max payload", base.DEC)
f.attempt = ProtoField.uint16("tdtp.attempt", "Attempt", base.DEC)
f.nonce = ProtoField.bytes("tdtp.nonce", "Nonce")
f.key_id = ProtoField.bytes("tdtp.key_id", "Key id")
f.cookie = ProtoField.bytes("tdtp.cookie", "Cookie")
f.path_token = ProtoField.bytes("tdtp.path_token", "Path token")
f.open_ack_pn = ProtoField.uint16("tdtp.open_ack.pn", "Packet number", base.DEC)
f.slave_nonce = ProtoField.bytes("tdtp.slave_nonce", "Slave nonce")
f.reason = ProtoField.uint8("tdtp.reason", "Reason", base.DEC, REASON_NAMES)
f.tag = ProtoField.bytes("tdtp.tag", "Authentication tag")
f.reset_echo = ProtoField.bytes("tdtp.reset.echo", "Echo (first 16 bytes of the datagram answered)")
f.reset_tag = ProtoField.bytes("tdtp.reset.tag", "Reset tag (HMAC under a key's reset key)")
f.pn = ProtoField.uint16("tdtp.pn", "Packet number (low 16 bits)", base.DEC)
f.sealed = ProtoField.bytes("tdtp.sealed", "Sealed body")
f.sealed_len = ProtoField.uint16("tdtp.sealed_len", "Sealed body length", base.DEC)
f.keyed = ProtoField.bool("tdtp.keyed", "Keyed session")
f.msg_seq = ProtoField.uint16("tdtp.message.seq", "Message number (low 16 bits)", base.DEC_HEX)
f.msg_ack = ProtoField.uint16("tdtp.message.ack", "Next message expected from the peer (low 16 bits)", base.DEC_HEX)
f.message = ProtoField.bytes("tdtp.message", "Control message")
f.message_len = ProtoField.uint16("tdtp.message_len", "Control message length", base.DEC)
f.path_id = ProtoField.uint8("tdtp.mp.path", "Path id", base.DEC)
f.mp_token = ProtoField.bytes("tdtp.mp.token", "Token")
f.mp_echo = ProtoField.bytes("tdtp.mp.echo", "Echo (the challenge's token)")
f.mp_seq = ProtoField.uint16("tdtp.mp.seq", "Newest SEQ received on the path", base.DEC_HEX, nil, 0x0FFF)
f.mp_hold = ProtoField.uint8("tdtp.mp.hold", "Its HOLD code", base.DEC, HOLD_NAMES)
f.mp_received = ProtoField.uint32("tdtp.mp.received", "DATA received on the path", base.DEC)
f.mp_first = ProtoField.uint32("tdtp.mp.first", "Of those, first copies", base.DEC)
f.mp_lag = ProtoField.uint16("tdtp.mp.lag", "Lag behind the first copy (100 us)", base.DEC)
f.mp_clock = ProtoField.uint32("tdtp.mp.clock", "Reporter's clock (us, low 32 bits)", base.DEC)
f.stamp = ProtoField.uint32("tdtp.stamp", "Sender's clock (us, low 32 bits)", base.DEC)

local e = tdtp.experts
e.truncated = ProtoExpert.new("tdtp.truncated", "Truncated: shorter than the 5-byte header",
    expert.group.MALFORMED, expert.severity.ERROR)
e.reserved_type = ProtoExpert.new("tdtp.reserved_type", "TYPE 3 is reserved (dropped as unknown_type)",
    expert.group.MALFORMED, expert.severity.ERROR)
e.empty_data = ProtoExpert.new("tdtp.empty_data", "DATA without payload (dropped as empty_data)",
    expert.group.MALFORMED, expert.severity.ERROR)
e.no_ack_fields = ProtoExpert.new("tdtp.no_ack_fields", "HOLD 255 (no acknowledgement) with ACK or SACK not zero",
    expert.group.PROTOCOL, expert.severity.WARN)
e.padding = ProtoExpert.new("tdtp.padding_nonzero", "ACK padding is not zero",
    expert.group.PROTOCOL, expert.severity.WARN)
e.bad_control = ProtoExpert.new("tdtp.bad_control", "Malformed control packet (dropped as bad_control)",
    expert.group.MALFORMED, expert.severity.ERROR)
e.unknown_code = ProtoExpert.new("tdtp.unknown_code", "Unknown control code (dropped as bad_control)",
    expert.group.MALFORMED, expert.severity.ERROR)
e.version = ProtoExpert.new("tdtp.unknown_version", "Not protocol version 4",
    expert.group.PROTOCOL, expert.severity.WARN)
e.flags = ProtoExpert.new("tdtp.bad_flags", "Inconsistent flags, suite or key id (dropped as bad_control)",
    expert.group.MALFORMED, expert.severity.ERROR)
e.reserved_flags = ProtoExpert.new("tdtp.reserved_flags", "Reserved flag bits set",
    expert.group.PROTOCOL, expert.severity.WARN)
e.zero_payload = ProtoExpert.new("tdtp.max_payload_zero", "max_payload 0 (dropped as bad_control)",
    expert.group.MALFORMED, expert.severity.ERROR)
e.hold_control = ProtoExpert.new("tdtp.control_hold", "This control packet must carry HOLD 255",
    expert.group.PROTOCOL, expert.severity.WARN)
e.keyed_short = ProtoExpert.new("tdtp.keyed_truncated", "Too short for packet number and tag (dropped as truncated)",
    expert.group.MALFORMED, expert.severity.ERROR)
e.sealed = ProtoExpert.new("tdtp.sealed_note", "Keyed session: body sealed, tag not verified (no keys)",
    expert.group.DECRYPTION, expert.severity.NOTE)
e.unverified_tag = ProtoExpert.new("tdtp.tag_note", "Authentication tag not verified (no keys)",
    expert.group.DECRYPTION, expert.severity.CHAT)

tdtp.prefs.ports = Pref.range("UDP ports", "", "UDP ports always decoded as TDTP (e.g. a slave's port)", 65535)
tdtp.prefs.keyed = Pref.enum("Keyed sessions", 0, "Whether DATA, ACK, KEEPALIVE and CLOSE carry the keyed layout",
    { { 1, "Learn from the OPEN or OPEN_ACK", 0 }, { 2, "Always keyed", 1 }, { 3, "Never keyed", 2 } }, false)
tdtp.prefs.heuristic = Pref.bool("Find TDTP by its handshake", true,
    "Claim UDP address pairs whose first TDTP packet seen is a well-formed handshake message")

-- Address pairs known to carry TDTP: key -> list of {frame, keyed} changes in frame order.
local sessions = {}
-- Master nonces (hex) seen in OPEN / OPEN_ACK -> whether that session is keyed: a multipath
-- session's new address pair learns its layout from the MP_CHALLENGE's nonce.
local nonces = {}

local function rshift(value, bits) return math.floor(value / 2 ^ bits) end
local function low_bits(value, bits) return value % 2 ^ bits end

local function pair_key(pinfo)
    local a = tostring(pinfo.src) .. "/" .. pinfo.src_port
    local b = tostring(pinfo.dst) .. "/" .. pinfo.dst_port
    if a < b then return a .. "|" .. b end
    return b .. "|" .. a
end

local function note_session(pinfo, keyed)
    if pinfo.visited then return end
    local key = pair_key(pinfo)
    local changes = sessions[key]
    if changes == nil then
        changes = {}
        sessions[key] = changes
    end
    local last = changes[#changes]
    if last == nil or (keyed ~= nil and last.keyed ~= keyed) then
        changes[#changes + 1] = { frame = pinfo.number, keyed = keyed }
    end
end

local function session_keyed(pinfo)
    local mode = tdtp.prefs.keyed
    if mode == 1 then return true end
    if mode == 2 then return false end
    local changes = sessions[pair_key(pinfo)]
    local keyed = false
    if changes ~= nil then
        for _, change in ipairs(changes) do
            if change.frame < pinfo.number and change.keyed ~= nil then keyed = change.keyed end
        end
    end
    return keyed
end

local function known_session(pinfo)
    local changes = sessions[pair_key(pinfo)]
    return changes ~= nil and changes[1].frame <= pinfo.number
end

-- HOLD code -> microseconds (section 3.4), nil for the reserved codes.
local function hold_us(code)
    if code > 253 then return nil end
    local exponent, mantissa = rshift(code, 5), low_bits(code, 5)
    local units = mantissa
    if exponent > 0 then units = (32 + mantissa) * 2 ^ (exponent - 1) end
    return units * 8
end

local function size_allowed(code, length)
    local sizes = CONTROL_SIZES[code]
    if sizes == nil then return false end
    for _, size in ipairs(sizes) do
        if size == length then return true end
    end
    return false
end

local function add_header(tree, tvb)
    local range = tvb(0, HEADER)
    local header = tree:add(tdtp, range, "Base header")
    header:add(f.type, tvb(0, 1))
    header:add(f.seq, tvb(0, 2))
    header:add(f.ack, tvb(1, 3))
    local sack_item = header:add(f.sack, tvb(3, 1))
    local hold_item = header:add(f.hold, tvb(4, 1))
    local ptype = range:bitfield(0, 2)
    local seq = range:bitfield(2, 12)
    local ack = range:bitfield(14, 12)
    local sack = range:bitfield(26, 6)
    local hold = range:bitfield(32, 8)
    local us = hold_us(hold)
    if us ~= nil then
        header:add(f.hold_us, tvb(4, 1), us):set_generated()
        hold_item:append_text(string.format(" (%d us)", us))
    end
    if hold == 255 then
        if ack ~= 0 or sack ~= 0 then header:add_proto_expert_info(e.no_ack_fields) end
    else
        header:add(f.acked, tvb(1, 3), ack):set_generated()
        local received = {}
        for i = 1, 6 do
            local number = (ack - i) % 4096
            if low_bits(rshift(sack, i - 1), 1) == 1 then
                header:add(f.acked, tvb(3, 1), number):set_generated()
                received[#received + 1] = string.format("ACK-%d", i)
            else
                header:add(f.absent, tvb(3, 1), number):set_generated()
            end
        end
        if #received > 0 then sack_item:append_text(" (received: " .. table.concat(received, " ") .. ")") end
    end
    return ptype, seq, ack, sack, hold, us
end

local function ack_text(ack, sack, hold, us)
    if hold == 255 then return "" end
    local text = string.format(" ack=%d sack=0x%02x", ack, sack)
    if us ~= nil then return text .. string.format(" hold=%dus", us) end
    return text .. " hold=saturated"
end

local function add_flags(tree, tvb, offset)
    local item = tree:add(f.flags, tvb(offset, 1))
    item:add(f.flag_separate, tvb(offset, 1))
    item:add(f.flag_keyed, tvb(offset, 1))
    item:add(f.flag_encrypted, tvb(offset, 1))
    item:add(f.flag_takeover, tvb(offset, 1))
    item:add(f.flag_timestamps, tvb(offset, 1))
    item:add(f.flag_multipath, tvb(offset, 1))
    item:add(f.flag_slave_dials, tvb(offset, 1))
    item:add(f.flag_reserved, tvb(offset, 1))
    local flags = tvb(offset, 1):uint()
    -- Bit 4 is reserved.
    if low_bits(rshift(flags, 4), 1) == 1 then item:add_proto_expert_info(e.reserved_flags) end
    return flags, item
end

local function flag_bit(flags, mask) return low_bits(math.floor(flags / mask), 1) == 1 end

local function add_sealed(tree, tvb, offset, length)
    -- prefix | PN | sealed body | tag (section 4.4)
    tree:add(f.pn, tvb(offset, PN))
    local body = length - offset - PN - TAG
    if body > 0 then
        tree:add(f.sealed, tvb(offset + PN, body))
    end
    tree:add(f.sealed_len, body):set_generated()
    tree:add(f.tag, tvb(length - TAG, TAG))
    tree:add_proto_expert_info(e.sealed)
    return tvb(offset, PN):uint(), body
end

-- CLOSE (unkeyed) and REJECT: the master's nonce and a reason.
-- A keyed session's control packet (code in the clear): its packet number and the length of its
-- sealed body, or nil and the summary when it is too short to hold them.
local function keyed_control(tree, tvb, length, name)
    if length < HEADER + 1 + PN + TAG then
        tree:add_proto_expert_info(e.keyed_short)
        return nil, name .. " (truncated)"
    end
    return add_sealed(tree, tvb, HEADER + 1, length)
end

local function close_fields(tree, tvb, length, name)
    if length ~= CONTROL_SIZES[5][1] then
        tree:add_proto_expert_info(e.bad_control)
        return name .. " (wrong length)"
    end
    tree:add(f.nonce, tvb(HEADER + 1, 16))
    tree:add(f.reason, tvb(HEADER + 17, 1))
    local reason = tvb(HEADER + 17, 1):uint()
    return name .. " " .. (REASON_NAMES[reason] or tostring(reason))
end

-- An address of a rendezvous message: family (4 or 6), port, 4 or 16 bytes. Returns the next offset
-- (nil if cut short).
local function add_address(tree, tvb, offset, length, label)
    if offset + 3 > length then return nil end
    local family = tvb(offset, 1):uint()
    local width = (family == 4 and 4) or (family == 6 and 16) or nil
    if width == nil or offset + 3 + width > length then return nil end
    local port = tvb(offset + 1, 2):uint()
    local host = width == 4 and tostring(tvb(offset + 3, 4):ipv4()) or tostring(tvb(offset + 3, 16):ipv6())
    tree:add(f.rv_address, tvb(offset, 3 + width), string.format("%s %s:%d", label, host, port))
    return offset + 3 + width
end

-- REGISTER, REFERRAL, PROBE, PROBE_ACK (section 5.12): never protected.
local function dissect_rendezvous(tvb, tree, length, code, name)
    if code == 23 or code == 24 then
        if length ~= 38 then
            tree:add_proto_expert_info(e.bad_control)
            return name .. " (wrong length)"
        end
        tree:add(f.rv_token, tvb(HEADER + 1, 16))
        tree:add(f.rv_mac, tvb(HEADER + 17, 16))
        return name
    end
    if length < HEADER + 20 then
        tree:add_proto_expert_info(e.bad_control)
        return name .. " (too short)"
    end
    tree:add(f.version, tvb(HEADER + 1, 1))
    if tvb(HEADER + 1, 1):uint() ~= VERSION then tree:add_proto_expert_info(e.version) end
    if code == 21 then
        if length < HEADER + 53 then
            tree:add_proto_expert_info(e.bad_control)
            return name .. " (too short)"
        end
        local item = tree:add(f.rv_flags, tvb(HEADER + 2, 1))
        item:add(f.rv_listener, tvb(HEADER + 2, 1))
        item:add(f.rv_leave, tvb(HEADER + 2, 1))
        tree:add(f.nonce, tvb(HEADER + 4, 16))
        tree:add(f.rv_id, tvb(HEADER + 20, 16))
        tree:add(f.cookie, tvb(HEADER + 36, 16))
        local offset = HEADER + 53
        for i = 1, tvb(HEADER + 52, 1):uint() do
            offset = add_address(tree, tvb, offset, length, "local")
            if offset == nil then break end
        end
        if offset ~= length then tree:add_proto_expert_info(e.bad_control) end
        local flags = tvb(HEADER + 2, 1):uint()
        local cookie_zero = tvb(HEADER + 36, 16):bytes():tohex() == string.rep("00", 16)
        return string.format("REGISTER%s%s%s", flag_bit(flags, 1) and " listener" or " dialer",
            flag_bit(flags, 2) and " leave" or "", cookie_zero and "" or " cookie")
    end
    tree:add(f.rv_kind, tvb(HEADER + 2, 1))
    tree:add(f.reason, tvb(HEADER + 3, 1))
    tree:add(f.nonce, tvb(HEADER + 4, 16))
    local kind = tvb(HEADER + 2, 1):uint()
    local text = "REFERRAL " .. (REFERRAL_KINDS[kind] or tostring(kind))
    local offset = HEADER + 20
    if kind == 0 then
        if length ~= offset + 16 then tree:add_proto_expert_info(e.bad_control) return text end
        tree:add(f.cookie, tvb(offset, 16))
        return text
    end
    if kind == 1 or kind == 2 then
        if length < offset + 2 then tree:add_proto_expert_info(e.bad_control) return text end
        tree:add(f.rv_lifetime, tvb(offset, 2))
        offset = add_address(tree, tvb, offset + 2, length, "reflexive (yours)")
        if offset ~= nil and kind == 2 then
            offset = add_address(tree, tvb, offset, length, "peer's reflexive")
            if offset ~= nil and offset + 2 <= length then
                local count = tvb(offset + 1, 1):uint()
                offset = offset + 2
                for i = 1, count do
                    offset = add_address(tree, tvb, offset, length, "peer's local")
                    if offset == nil then break end
                end
            else
                offset = nil
            end
        end
        if offset ~= length then tree:add_proto_expert_info(e.bad_control) end
    end
    return text
end

local function dissect_control(tvb, pinfo, tree, length, keyed, hold)
    local code = tvb(HEADER, 1):uint()
    local name = CODE_NAMES[code]
    tree:add(f.code, tvb(HEADER, 1))
    if name == nil then
        tree:add_proto_expert_info(e.unknown_code)
        return string.format("CONTROL code %d", code)
    end
    -- KEEPALIVE, TIMESTAMP and TIMED_DATA carry an acknowledgement; the others HOLD 255.
    if code ~= 3 and code ~= 15 and code ~= 16 and hold ~= 255 then tree:add_proto_expert_info(e.hold_control) end
    if code >= 21 then return dissect_rendezvous(tvb, tree, length, code, name) end
    if code == 1 or code == 2 then
        -- OPEN / OPEN_ACK: fields in the clear, a 16-byte tag when KEYED.
        if length < HEADER + 3 then
            tree:add_proto_expert_info(e.bad_control)
            return name
        end
        tree:add(f.version, tvb(HEADER + 1, 1))
        local version = tvb(HEADER + 1, 1):uint()
        if version ~= VERSION then
            tree:add_proto_expert_info(e.version)
            return string.format("%s version %d", name, version)
        end
        local flags = add_flags(tree, tvb, HEADER + 2)
        local is_keyed = flag_bit(flags, 2)
        if length ~= CONTROL_SIZES[code][is_keyed and 2 or 1] then
            tree:add_proto_expert_info(e.bad_control)
            return name .. " (wrong length)"
        end
        tree:add(f.suite, tvb(HEADER + 3, 1))
        tree:add(f.max_payload, tvb(HEADER + 4, 2))
        local suite = tvb(HEADER + 3, 1):uint()
        local max_payload = tvb(HEADER + 4, 2):uint()
        if max_payload == 0 then tree:add_proto_expert_info(e.zero_payload) end
        local text
        if code == 1 then
            tree:add(f.attempt, tvb(HEADER + 6, 2))
            tree:add(f.nonce, tvb(HEADER + 8, 16))
            tree:add(f.key_id, tvb(HEADER + 24, 8))
            tree:add(f.cookie, tvb(HEADER + 32, 16))
            local key_zero = tvb(HEADER + 24, 8):bytes():tohex() == "0000000000000000"
            if (flag_bit(flags, 4) and not is_keyed) or (is_keyed ~= (suite ~= 0))
                or (not is_keyed and not key_zero) then
                tree:add_proto_expert_info(e.flags)
            end
            local cookie_zero = tvb(HEADER + 32, 16):bytes():tohex() == string.rep("00", 16)
            text = string.format("OPEN attempt=%d max_payload=%d%s%s", tvb(HEADER + 6, 2):uint(),
                max_payload, cookie_zero and "" or " cookie", is_keyed and " keyed" or "")
        else
            tree:add(f.open_ack_pn, tvb(HEADER + 6, 2))
            tree:add(f.nonce, tvb(HEADER + 8, 16))
            tree:add(f.slave_nonce, tvb(HEADER + 24, 16))
            if (flag_bit(flags, 4) and not is_keyed) or (is_keyed ~= (suite ~= 0)) then
                tree:add_proto_expert_info(e.flags)
            end
            text = string.format("OPEN_ACK max_payload=%d%s", max_payload, is_keyed and " keyed" or "")
        end
        if is_keyed then
            tree:add(f.tag, tvb(length - TAG, TAG))
            tree:add_proto_expert_info(e.unverified_tag)
        end
        if flag_bit(flags, 1) then text = text .. " separate-acks" end
        if flag_bit(flags, 64) then text = text .. " multipath" end
        nonces[tvb(HEADER + 8, 16):bytes():tohex()] = is_keyed
        note_session(pinfo, is_keyed)
        return text
    end
    if code == 6 then
        if length ~= CONTROL_SIZES[6][1] then
            tree:add_proto_expert_info(e.bad_control)
            return "COOKIE (wrong length)"
        end
        tree:add(f.version, tvb(HEADER + 1, 1))
        if tvb(HEADER + 1, 1):uint() ~= VERSION then tree:add_proto_expert_info(e.version) end
        tree:add(f.nonce, tvb(HEADER + 2, 16))
        tree:add(f.cookie, tvb(HEADER + 18, 16))
        note_session(pinfo, nil)
        return "COOKIE"
    end
    if code == 5 then
        note_session(pinfo, nil)
        return close_fields(tree, tvb, length, "REJECT")
    end
    if code == 7 then
        -- RESET (section 5.7): never protected; an echo, then whole 16-byte tags when keyed.
        local rest = length - HEADER - 1 - RESET_ECHO
        if rest < 0 or rest % TAG ~= 0 then
            tree:add_proto_expert_info(e.bad_control)
            return "RESET (wrong length)"
        end
        tree:add(f.reset_echo, tvb(HEADER + 1, RESET_ECHO))
        local tags = math.floor(rest / TAG)
        for i = 0, tags - 1 do
            tree:add(f.reset_tag, tvb(HEADER + 1 + RESET_ECHO + i * TAG, TAG))
        end
        return string.format("RESET tags=%d", tags)
    end
    -- Path validation (unkeyed sessions): always in the clear.
    if code == 8 or code == 9 then
        if length ~= CONTROL_SIZES[code][1] then
            tree:add_proto_expert_info(e.bad_control)
            return name .. " (wrong length)"
        end
        tree:add(f.path_token, tvb(HEADER + 1, 16))
        if code == 9 then tree:add(f.nonce, tvb(HEADER + 17, 16)) end
        return name
    end
    -- Multipath (section 5.11): a challenge or response carries the master's nonce in the clear.
    if code == 17 or code == 18 then
        local is_keyed = length == CONTROL_SIZES[code][2]
        if not size_allowed(code, length) then
            tree:add_proto_expert_info(e.bad_control)
            return name .. " (wrong length)"
        end
        tree:add(f.nonce, tvb(HEADER + 1, 16))
        note_session(pinfo, is_keyed)
        if is_keyed then
            local pn = add_sealed(tree, tvb, HEADER + 17, length)
            return string.format("%s pn=%d", name, pn)
        end
        tree:add(f.path_id, tvb(HEADER + 17, 1))
        local path = tvb(HEADER + 17, 1):uint()
        if code == 17 then
            tree:add(f.mp_token, tvb(HEADER + 18, 8))
            return string.format("MP_CHALLENGE path=%d", path)
        end
        tree:add(f.mp_echo, tvb(HEADER + 18, 8))
        tree:add(f.mp_token, tvb(HEADER + 26, 8))
        return string.format("MP_RESPONSE path=%d", path)
    end
    if code == 19 or code == 20 then
        if keyed then
            if length ~= CONTROL_SIZES[code][2] then tree:add_proto_expert_info(e.bad_control) end
            if length < HEADER + 1 + PN + TAG then return name .. " (truncated)" end
            local pn = add_sealed(tree, tvb, HEADER + 1, length)
            return string.format("%s pn=%d", name, pn)
        end
        if length ~= CONTROL_SIZES[code][1] then
            tree:add_proto_expert_info(e.bad_control)
            return name .. " (wrong length)"
        end
        if code == 20 then
            tree:add(f.nonce, tvb(HEADER + 1, 16))
            tree:add(f.path_id, tvb(HEADER + 17, 1))
            tree:add(f.reason, tvb(HEADER + 18, 1))
            local reason = tvb(HEADER + 18, 1):uint()
            return string.format("MP_ABANDON path=%d %s", tvb(HEADER + 17, 1):uint(),
                REASON_NAMES[reason] or tostring(reason))
        end
        tree:add(f.nonce, tvb(HEADER + 1, 16))
        tree:add(f.path_id, tvb(HEADER + 17, 1))
        tree:add(f.mp_seq, tvb(HEADER + 18, 2))
        tree:add(f.mp_hold, tvb(HEADER + 20, 1))
        tree:add(f.mp_received, tvb(HEADER + 21, 4))
        tree:add(f.mp_first, tvb(HEADER + 25, 4))
        tree:add(f.mp_lag, tvb(HEADER + 29, 2))
        tree:add(f.mp_clock, tvb(HEADER + 31, 4))
        return string.format("MP_REPORT path=%d received=%d first=%d", tvb(HEADER + 17, 1):uint(),
            tvb(HEADER + 21, 4):uint(), tvb(HEADER + 25, 4):uint())
    end
    -- Send timestamps (section 5.13): an ACK's or a DATA's stand-in, protected in a keyed session.
    if code == 15 or code == 16 then
        if keyed then
            local pn, sealed = keyed_control(tree, tvb, length, name)
            if pn == nil then return sealed end
            if (code == 15 and sealed ~= STAMP - 1) or (code == 16 and sealed < STAMP) then
                tree:add_proto_expert_info(e.bad_control)
            end
            return string.format("%s pn=%d", name, pn)
        end
        if (code == 15 and length ~= HEADER + STAMP) or (code == 16 and length <= HEADER + STAMP) then
            tree:add_proto_expert_info(e.bad_control)
            return name .. " (wrong length)"
        end
        tree:add(f.stamp, tvb(HEADER + 1, 4))
        local stamp = tvb(HEADER + 1, 4):uint()
        if code == 15 then
            return string.format("TIMESTAMP time=%d", stamp)
        end
        local data = length - HEADER - STAMP
        tree:add(f.payload_len, data):set_generated()
        tree:add(f.payload, tvb(HEADER + STAMP, data))
        return string.format("TIMED_DATA time=%d len=%d", stamp, data)
    end
    -- The reliable control channel (section 5.10): session control, protected in a keyed session.
    if code == 10 or code == 11 then
        if keyed then
            local pn, sealed = keyed_control(tree, tvb, length, name)
            if pn == nil then return sealed end
            -- Sealed: the nonce and the numbers (MESSAGE: and at least one message byte).
            if (code == 10 and sealed < MESSAGE_PREFIX) or (code == 11 and sealed ~= MESSAGE_ACK - 1) then
                tree:add_proto_expert_info(e.bad_control)
            end
            return string.format("%s pn=%d", name, pn)
        end
        -- Both carry the master's nonce after the code byte (version 4), then the numbers.
        if code == 11 then
            if length ~= HEADER + MESSAGE_ACK then
                tree:add_proto_expert_info(e.bad_control)
                return name .. " (wrong length)"
            end
            tree:add(f.nonce, tvb(HEADER + 1, 16))
            tree:add(f.msg_ack, tvb(HEADER + 17, 2))
            return string.format("MESSAGE_ACK next=%d", tvb(HEADER + 17, 2):uint())
        end
        if length < HEADER + MESSAGE_PREFIX + 1 then
            tree:add_proto_expert_info(e.bad_control)
            return name .. " (no message)"
        end
        local data = length - HEADER - MESSAGE_PREFIX
        tree:add(f.nonce, tvb(HEADER + 1, 16))
        tree:add(f.msg_seq, tvb(HEADER + 17, 2))
        tree:add(f.msg_ack, tvb(HEADER + 19, 2))
        tree:add(f.message_len, data):set_generated()
        tree:add(f.message, tvb(HEADER + MESSAGE_PREFIX, data))
        return string.format("MESSAGE seq=%d next=%d len=%d", tvb(HEADER + 17, 2):uint(),
            tvb(HEADER + 19, 2):uint(), data)
    end
    -- KEEPALIVE and CLOSE: session control, protected in a keyed session.
    if keyed then
        local pn, sealed = keyed_control(tree, tvb, length, name)
        if pn == nil then return sealed end
        -- What is sealed: the body after the code byte, less the packet number and the tag.
        if sealed ~= CONTROL_SIZES[code][2] - HEADER - 1 - PN - TAG then
            tree:add_proto_expert_info(e.bad_control)
        end
        return string.format("%s pn=%d", name, pn)
    end
    if code == 3 then
        if length ~= CONTROL_SIZES[3][1] then
            tree:add_proto_expert_info(e.bad_control)
        else
            tree:add(f.nonce, tvb(HEADER + 1, 16))
        end
        return "KEEPALIVE"
    end
    return close_fields(tree, tvb, length, "CLOSE")
end

function tdtp.dissector(tvb, pinfo, tree)
    local length = tvb:len()
    pinfo.cols.protocol = "TDTP"
    local root = tree:add(tdtp, tvb(), "Teleoperation Data Transport Protocol")
    if length < HEADER then
        root:add_proto_expert_info(e.truncated)
        pinfo.cols.info = "TDTP truncated"
        return length
    end
    local keyed = session_keyed(pinfo)
    local ptype, seq, ack, sack, hold, us = add_header(root, tvb)
    local info
    local handshake = false
    if ptype == 2 and length > HEADER then
        local code = tvb(HEADER, 1):uint()
        handshake = code == 1 or code == 2 or code == 5 or code == 6 or code == 7 or code == 8
            or code == 9 or code == 17 or code == 18 or code >= 21
    end
    if not handshake then root:add(f.keyed, keyed):set_generated() end
    if ptype == 3 then
        root:add_proto_expert_info(e.reserved_type)
        info = "reserved TYPE 3"
    elseif ptype == 2 then
        if length == HEADER then
            root:add_proto_expert_info(e.bad_control)
            info = "CONTROL without a code"
        else
            local code = tvb(HEADER, 1):uint()
            info = dissect_control(tvb, pinfo, root, length, keyed and not handshake, hold)
            if code == 3 or code == 4 then info = info .. string.format(" seq=%d", seq) .. ack_text(ack, sack, hold, us) end
        end
    elseif keyed then
        -- DATA or ACK with the keyed layout: header | PN | sealed body | tag.
        local name = TYPE_NAMES[ptype]
        if length < HEADER + PN + TAG then
            root:add_proto_expert_info(e.keyed_short)
            info = name .. " (truncated)"
        else
            local pn, sealed = add_sealed(root, tvb, HEADER, length)
            if ptype == 0 and sealed == 0 then root:add_proto_expert_info(e.empty_data) end
            info = string.format("%s seq=%d", name, seq) .. ack_text(ack, sack, hold, us)
                .. string.format(" pn=%d len=%d", pn, sealed)
        end
    elseif ptype == 0 then
        local payload = length - HEADER
        root:add(f.payload_len, payload):set_generated()
        if payload == 0 then
            root:add_proto_expert_info(e.empty_data)
        else
            root:add(f.payload, tvb(HEADER, payload))
        end
        info = string.format("DATA seq=%d", seq) .. ack_text(ack, sack, hold, us)
            .. string.format(" len=%d", payload)
    else
        if length > HEADER then
            local padding = tvb(HEADER, length - HEADER)
            local item = root:add(f.padding, padding)
            if padding:bytes():tohex() ~= string.rep("00", length - HEADER) then
                item:add_proto_expert_info(e.padding)
            end
        end
        info = string.format("ACK seq=%d", seq) .. ack_text(ack, sack, hold, us)
    end
    pinfo.cols.info = info
    return length
end

-- The heuristic: a well-formed handshake message starts a TDTP address pair; later datagrams of
-- a known pair are TDTP whatever they contain (malformed ones then get expert info).
local function heuristic(tvb, pinfo, tree)
    if not tdtp.prefs.heuristic then return false end
    local length = tvb:len()
    if known_session(pinfo) then
        tdtp.dissector(tvb, pinfo, tree)
        return true
    end
    if length < HEADER + 1 then return false end
    local first = tvb(0, 1):uint()
    if rshift(first, 6) ~= 2 then return false end
    local code = tvb(HEADER, 1):uint()
    local plain = tvb(0, 4):uint() == 0x80000000 and tvb(4, 1):uint() == 255
    local rendezvous = (code == 21 or code == 22) and length >= HEADER + 20
        and tvb(HEADER + 1, 1):uint() == VERSION
    if plain and (rendezvous or ((code == 23 or code == 24) and length == 38)) then
        note_session(pinfo, nil) -- a relay's pairs, and a punched path: their sessions too
        tdtp.dissector(tvb, pinfo, tree)
        return true
    end
    if code == 17 and size_allowed(code, length) and tvb(4, 1):uint() == 255 then
        -- A multipath session's new path: claimed when its nonce is a session's seen before (or
        -- when nothing was seen: a capture of the new path alone).
        local nonce = tvb(HEADER + 1, 16):bytes():tohex()
        local keyed = nonces[nonce]
        if keyed == nil then keyed = length == CONTROL_SIZES[17][2] end
        note_session(pinfo, keyed)
        tdtp.dissector(tvb, pinfo, tree)
        return true
    end
    if code ~= 1 and code ~= 2 and code ~= 5 and code ~= 6 then return false end
    if not size_allowed(code, length) or tvb(4, 1):uint() ~= 255 then return false end
    if code ~= 5 and tvb(HEADER + 1, 1):uint() ~= VERSION then return false end
    if code == 6 or code == 5 then
        if tvb(0, 4):uint() ~= 0x80000000 then return false end -- SEQ, ACK, SACK all zero
    end
    note_session(pinfo, nil)
    tdtp.dissector(tvb, pinfo, tree)
    return true
end

tdtp:register_heuristic("udp", heuristic)

local registered_ports = ""
function tdtp.prefs_changed()
    local udp = DissectorTable.get("udp.port")
    if registered_ports ~= "" then udp:remove(registered_ports, tdtp) end
    registered_ports = tostring(tdtp.prefs.ports)
    if registered_ports ~= "" then udp:add(registered_ports, tdtp) end
end

function tdtp.init()
    sessions = {}
    nonces = {}
end
