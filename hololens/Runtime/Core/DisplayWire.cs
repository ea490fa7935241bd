// The downlink of docs/headset_wire_format.md: display messages from headset_display and
// clock_ping from gaze_bridge. Decode is the headset's trust boundary: for any bytes it returns
// a DownlinkMessage or throws WireError with a reason, nothing else.
using System;
using System.Collections.Generic;
using System.Text;

namespace FabricGuidance.Headset
{
    public sealed class WireError : Exception
    {
        public readonly string Reason;
        public WireError(string reason, string message) : base(message) { Reason = reason; }
    }

    public struct DisplayTarget
    {
        public string Id, Role;   // role: "target" or "live"
        public Vec3 Position;     // Unity world, metres
    }

    public sealed class DownlinkMessage
    {
        public string Kind;
        public uint Seq;          // display messages
        public double Stamp;      // display messages: the PC's ROS time
        // targets
        public string Active;
        public List<DisplayTarget> Targets;
        // dummies
        public uint Set, Part, Parts;
        public double RadiusM;
        public List<Vec3> Positions;
        // event
        public uint EventId;
        public string Event, Target;
        // prompt, phrase
        public string Text;
        public uint Step, Steps;
        // clock_ping
        public uint PingSeq;
        public double T1;
        public string T1Text;
    }

    public static class DisplayWire
    {
        public const int MaxBytes = 1200;
        public const int MaxIdChars = 32, MaxTextChars = 200, MaxTargets = 8, MaxDummiesPerPart = 25, MaxDummyParts = 8;
        public const double MaxAbsPosition = 1.0e4;
        public static readonly string[] DisplayKinds = { "targets", "dummies", "event", "prompt", "phrase" };
        static readonly UTF8Encoding StrictUtf8 = new UTF8Encoding(false, true);

        public static DownlinkMessage Decode(byte[] data, int length)
        {
            if (length > MaxBytes) throw new WireError("oversize", "datagram of " + length + " bytes exceeds " + MaxBytes);
            string text;
            try { text = StrictUtf8.GetString(data, 0, length); }
            catch (ArgumentException) { throw new WireError("encoding", "datagram is not UTF-8"); }
            JsonValue root;
            try { root = Json.Parse(text); }
            catch (JsonError e) { throw new WireError(e.Reason, e.Message); }
            if (root.Kind != JsonKind.Object) throw new WireError("not_object", "datagram is " + root.TypeName() + ", not an object");
            var o = root.Object;
            long version = Integer(o, "version", "version");
            if (version != 1) throw new WireError("version", "version " + version + " is not supported (expected 1)");
            JsonValue kindValue = Get(o, "kind");
            if (kindValue.Kind != JsonKind.String) throw new WireError("type", "kind must be a string, got " + kindValue.TypeName());
            var m = new DownlinkMessage { Kind = kindValue.String };
            if (m.Kind == "clock_ping")
            {
                m.PingSeq = UInt(o, "ping_seq");
                JsonValue t1 = Get(o, "t1");
                m.T1 = Number(t1, "t1");
                m.T1Text = t1.Text;
                return m;
            }
            if (Array.IndexOf(DisplayKinds, m.Kind) < 0)
                throw new WireError("kind", "kind '" + Json.Cut(m.Kind) + "' is not a display message");
            m.Seq = UInt(o, "seq");
            m.Stamp = Number(Get(o, "stamp"), "stamp");
            switch (m.Kind)
            {
                case "targets":
                    m.Active = Str(Get(o, "active"), "active", MaxIdChars);
                    m.Targets = new List<DisplayTarget>();
                    var items = Arr(Get(o, "targets"), "targets", MaxTargets);
                    for (int i = 0; i < items.Count; i++)
                    {
                        string where = "targets[" + i + "]";
                        if (items[i].Kind != JsonKind.Object) throw new WireError("type", where + " must be an object, got " + items[i].TypeName());
                        var t = items[i].Object;
                        var dt = new DisplayTarget
                        {
                            Id = Str(Get(t, "id"), where + ".id", MaxIdChars),
                            Position = Point(Get(t, "position"), where + ".position"),
                            Role = Str(Get(t, "role"), where + ".role", MaxIdChars),
                        };
                        if (dt.Role != "target" && dt.Role != "live") throw new WireError("range", where + ".role '" + dt.Role + "' is not target or live");
                        m.Targets.Add(dt);
                    }
                    break;
                case "dummies":
                    m.Set = UInt(o, "set");
                    m.Part = UInt(o, "part");
                    m.Parts = UInt(o, "parts");
                    m.RadiusM = Number(Get(o, "radius_m"), "radius_m");
                    if (!(m.RadiusM > 0.0 && m.RadiusM <= 10.0)) throw new WireError("range", "radius_m " + m.RadiusM + " is outside (0, 10] m");
                    m.Positions = new List<Vec3>();
                    var ps = Arr(Get(o, "positions"), "positions", MaxDummiesPerPart);
                    for (int i = 0; i < ps.Count; i++) m.Positions.Add(Point(ps[i], "positions[" + i + "]"));
                    if (!(m.Part < m.Parts && m.Parts <= MaxDummyParts))
                        throw new WireError("range", "dummies part " + m.Part + " of " + m.Parts + ": needs 0 <= part < parts <= " + MaxDummyParts);
                    break;
                case "event":
                    m.EventId = UInt(o, "event_id");
                    m.Event = Str(Get(o, "event"), "event", MaxIdChars);
                    if (m.Event != "found" && m.Event != "next" && m.Event != "done") throw new WireError("range", "event '" + m.Event + "' is not found, next or done");
                    m.Target = Str(Get(o, "target"), "target", MaxIdChars);
                    break;
                case "prompt":
                    m.Text = Str(Get(o, "text"), "text", MaxTextChars);
                    m.Step = UInt(o, "step");
                    m.Steps = UInt(o, "steps");
                    break;
                case "phrase":
                    m.Text = Str(Get(o, "text"), "text", MaxTextChars);
                    break;
            }
            return m;
        }

        static JsonValue Get(Dictionary<string, JsonValue> o, string name)
        {
            JsonValue v;
            if (!o.TryGetValue(name, out v)) throw new WireError("missing_field", "field '" + name + "' is missing");
            return v;
        }

        static long Integer(Dictionary<string, JsonValue> o, string name, string hugeReason)
        {
            JsonValue v = Get(o, name);
            if (v.Kind != JsonKind.Number || !v.IsInteger) throw new WireError("type", name + " must be an integer, got " + v.TypeName());
            long n;
            if (!long.TryParse(v.Text, System.Globalization.NumberStyles.AllowLeadingSign, System.Globalization.CultureInfo.InvariantCulture, out n))
                throw new WireError(hugeReason, name + " " + Json.Cut(v.Text) + " is too long");
            return n;
        }

        static uint UInt(Dictionary<string, JsonValue> o, string name)
        {
            long n = Integer(o, name, "range");
            if (n < 0 || n > uint.MaxValue) throw new WireError("range", name + " " + n + " is outside 0..2**32-1");
            return (uint)n;
        }

        static double Number(JsonValue v, string name)
        {
            if (v.Kind != JsonKind.Number) throw new WireError("type", name + " must be a number, got " + v.TypeName());
            return v.Number;
        }

        static string Str(JsonValue v, string name, int limit)
        {
            if (v.Kind != JsonKind.String) throw new WireError("type", name + " must be a string, got " + v.TypeName());
            // Python counts code points; a character beyond the BMP is two UTF-16 units here.
            int chars = 0;
            for (int i = 0; i < v.String.Length; i++) if (!char.IsLowSurrogate(v.String[i])) chars++;
            if (chars > limit) throw new WireError("range", name + " has " + chars + " characters, more than " + limit);
            return v.String;
        }

        static List<JsonValue> Arr(JsonValue v, string name, int limit)
        {
            if (v.Kind != JsonKind.Array) throw new WireError("type", name + " must be an array, got " + v.TypeName());
            if (v.Array.Count > limit) throw new WireError("range", name + " has " + v.Array.Count + " items, more than " + limit);
            return v.Array;
        }

        static Vec3 Point(JsonValue v, string name)
        {
            if (v.Kind != JsonKind.Array || v.Array.Count != 3) throw new WireError("type", name + " must be an array of 3 numbers, got " + v.TypeName());
            var p = new Vec3(Number(v.Array[0], name + "[0]"), Number(v.Array[1], name + "[1]"), Number(v.Array[2], name + "[2]"));
            if (Math.Abs(p.X) > MaxAbsPosition || Math.Abs(p.Y) > MaxAbsPosition || Math.Abs(p.Z) > MaxAbsPosition)
                throw new WireError("range", name + " is more than 10000 m from the origin");
            return p;
        }
    }
}
