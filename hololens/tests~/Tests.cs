// The core's tests, run with mono by `make -C hololens test` (no test framework is packaged
// for Debian's mono; this runner prints each failure and the closing line "N passed, N failed").
using System;
using System.Collections.Generic;
using System.Globalization;
using System.IO;
using System.Net;
using System.Net.Sockets;
using System.Text;
using System.Threading;
using FabricGuidance.Headset;

static class Tests
{
    static readonly List<KeyValuePair<string, Action>> All = new List<KeyValuePair<string, Action>>();
    static void Test(string name, Action body) { All.Add(new KeyValuePair<string, Action>(name, body)); }

    static void True(bool condition, string what) { if (!condition) throw new Exception(what); }
    static void Equal<T>(T expected, T got, string what)
    {
        if (!EqualityComparer<T>.Default.Equals(expected, got)) throw new Exception(what + ": expected " + expected + ", got " + got);
    }
    static void Rejects(string reason, string json)
    {
        byte[] b = Encoding.UTF8.GetBytes(json);
        try { DisplayWire.Decode(b, b.Length); }
        catch (WireError e) { Equal(reason, e.Reason, "reason for " + json + " (" + e.Message + ")"); return; }
        throw new Exception("accepted: " + json);
    }
    static DownlinkMessage Decode(string json)
    {
        byte[] b = Encoding.UTF8.GetBytes(json);
        return DisplayWire.Decode(b, b.Length);
    }

    /// <summary>The next datagram at `sock`, calling `pump` (the owner's frame) while it waits.</summary>
    static string ReceiveWhilePumping(UdpClient sock, Func<int> pump, double seconds)
    {
        var deadline = DateTime.UtcNow.AddSeconds(seconds);
        var from = new IPEndPoint(IPAddress.Any, 0);
        while (DateTime.UtcNow < deadline)
        {
            pump();
            if (sock.Available > 0) return Encoding.UTF8.GetString(sock.Receive(ref from));
            Thread.Sleep(2);
        }
        throw new Exception("nothing arrived within " + seconds + " s");
    }

    /// <summary>A clock like Unity's Time: it throws on any thread but the one that made it (and
    /// notes it, since an exception on the receive thread would go unseen).</summary>
    sealed class MainThreadClock : IHeadsetClock
    {
        public readonly int Owner = Thread.CurrentThread.ManagedThreadId;
        public int OffThread;
        readonly StopwatchClock inner = new StopwatchClock(700.0);
        public void Check(string what)
        {
            if (Thread.CurrentThread.ManagedThreadId == Owner) return;
            Interlocked.Increment(ref OffThread);
            throw new InvalidOperationException(what + " can only be called from the main thread");
        }
        public double Now() { Check("get_realtimeSinceStartupAsDouble"); return inner.Now(); }
    }

    /// <summary>DisplayRenderer without Unity: binds to a session's display in Start, draws in LateUpdate.</summary>
    sealed class Renderer
    {
        DisplayState state;
        public int Targets = -1;
        public string Flashed = "";
        public void Start(HeadsetSession session, MainThreadClock clock)
        {
            state = session.Display;
            state.EventShown += m => { clock.Check("EventShown"); if (m.Event == "found") Flashed = m.Target; };
        }
        public void LateUpdate() { Targets = state.Targets.Count; }
    }

    sealed class EyeSource : IEyeGazeSource
    {
        public bool Tracked;
        public Vec3 Origin, Direction;   // what the device returns, tracked or not
        public bool TryGetEyeGaze(out Vec3 origin, out Vec3 direction)
        {
            origin = Origin;
            direction = Direction;
            return Tracked;
        }
    }

    static GazeFrame Frame(double x)
    {
        return new GazeFrame
        {
            GazeOrigin = new Vec3(x, 1.6, -0.012), GazeDirection = new Vec3(0.259, -0.087, 0.962),
            HeadPosition = new Vec3(0.03, 1.64, -0.05), HeadOrientation = new Quat(0, 0.130526, 0, 0.991445),
            EyeTrackingValid = true,
        };
    }

    /// <summary>All tests, or those whose name contains the first argument.</summary>
    static int Main(string[] args)
    {
        Test("gaze numbers are invariant whatever the thread's culture", () =>
        {
            foreach (string name in new[] { "de-DE", "fr-FR", "ar-SA", "fa-IR", "ru-RU", "" })
            {
                Thread.CurrentThread.CurrentCulture = new CultureInfo(name);
                string text = Encoding.UTF8.GetString(GazeWire.Encode(4294967295u, 3605.2113, Frame(0.5)));
                True(!text.Contains("0,5") && text.Contains("[0.5,1.6,-0.012]"), name + ": " + text);
                var v = Json.Parse(text);
                Equal(3605.2113, v.Object["stamp"].Number, name + " stamp");
                Equal("4294967295", v.Object["seq"].Text, name + " seq");
            }
            Thread.CurrentThread.CurrentCulture = CultureInfo.InvariantCulture;
        });
        Test("gaze datagram has the fields of the format, in its order, and round-trips its numbers", () =>
        {
            string text = Encoding.UTF8.GetString(GazeWire.Encode(1042, 3605.2113, Frame(0.031)));
            var o = Json.Parse(text).Object;
            string[] fields = { "version", "seq", "stamp", "gaze_origin", "gaze_direction", "head_position", "head_orientation", "eye_tracking_valid" };
            int last = -1;
            foreach (string f in fields)
            {
                int at = text.IndexOf("\"" + f + "\"", StringComparison.Ordinal);
                True(at > last, f + " out of order in " + text);
                last = at;
            }
            Equal(0.130526, o["head_orientation"].Array[1].Number, "head_orientation y");
            Equal(JsonKind.True, o["eye_tracking_valid"].Kind, "eye_tracking_valid");
            True(text.Length < GazeWire.MaxBytes, "size");
            // The value a float from Unity becomes is carried exactly (the double of the float).
            float f32 = 0.1f;
            string t2 = Encoding.UTF8.GetString(GazeWire.Encode(0, 0, new GazeFrame { GazeDirection = new Vec3(f32, 0, 1), HeadOrientation = new Quat(0, 0, 0, 1) }));
            Equal((double)f32, Json.Parse(t2).Object["gaze_direction"].Array[0].Number, "float carried");
        });
        Test("a frame with NaN or infinity is not encoded", () =>
        {
            var f = Frame(0);
            f.GazeDirection = new Vec3(double.NaN, 0, 1);
            True(GazeWire.Encode(0, 1, f) == null, "NaN direction");
            f = Frame(0);
            f.HeadOrientation = new Quat(0, 0, double.PositiveInfinity, 1);
            True(GazeWire.Encode(0, 1, f) == null, "infinite orientation");
            True(GazeWire.Encode(0, double.NaN, Frame(0)) == null, "NaN stamp");
        });
        Test("the Python encoder's datagram reads back as the C# encoder writes it", () =>
        {
            // fixtures/python_gaze.json: fabric_guidance.core.gaze_wire.encode_datagram output (see the file's generator line).
            string[] lines = File.ReadAllLines("fixtures/python_gaze.jsonl");
            int n = 0;
            foreach (string line in lines)
            {
                if (line.StartsWith("#")) continue;
                var py = Json.Parse(line).Object;
                var go = py["gaze_origin"].Array;
                var gd = py["gaze_direction"].Array;
                var hp = py["head_position"].Array;
                var ho = py["head_orientation"].Array;
                var frame = new GazeFrame
                {
                    GazeOrigin = new Vec3(go[0].Number, go[1].Number, go[2].Number),
                    GazeDirection = new Vec3(gd[0].Number, gd[1].Number, gd[2].Number),
                    HeadPosition = new Vec3(hp[0].Number, hp[1].Number, hp[2].Number),
                    HeadOrientation = new Quat(ho[0].Number, ho[1].Number, ho[2].Number, ho[3].Number),
                    EyeTrackingValid = py["eye_tracking_valid"].Kind == JsonKind.True,
                };
                var cs = Json.Parse(Encoding.UTF8.GetString(GazeWire.Encode(uint.Parse(py["seq"].Text), py["stamp"].Number, frame))).Object;
                foreach (var kv in py)
                {
                    True(cs.ContainsKey(kv.Key), "C# lacks " + kv.Key);
                    if (kv.Value.Kind == JsonKind.Array)
                        for (int i = 0; i < kv.Value.Array.Count; i++)
                            Equal(kv.Value.Array[i].Number, cs[kv.Key].Array[i].Number, kv.Key + "[" + i + "]");
                    else if (kv.Value.Kind == JsonKind.Number)
                        Equal(kv.Value.Number, cs[kv.Key].Number, kv.Key);
                }
                n++;
            }
            True(n >= 3, "fixture lines: " + n);
        });
        Test("display fixtures written by the Python encoder decode", () =>
        {
            int n = 0;
            foreach (string line in File.ReadAllLines("fixtures/python_display.jsonl"))
            {
                if (line.StartsWith("#")) continue;
                var m = Decode(line);
                var py = Json.Parse(line).Object;
                Equal(py["kind"].String, m.Kind, "kind");
                if (m.Kind == "targets")
                {
                    Equal(py["targets"].Array.Count, m.Targets.Count, "targets");
                    Equal(py["targets"].Array[0].Object["position"].Array[2].Number, m.Targets[0].Position.Z, "z");
                }
                if (m.Kind == "dummies") Equal(py["positions"].Array.Count, m.Positions.Count, "dummies");
                if (m.Kind == "prompt") Equal(py["text"].String, m.Text, "prompt text");
                n++;
            }
            True(n >= 5, "fixture lines: " + n);
        });
        Test("every rejection reason of the downlink", () =>
        {
            string ok = "\"version\":1,\"kind\":\"phrase\",\"seq\":1,\"stamp\":2.5";
            var big = new byte[DisplayWire.MaxBytes + 1];
            for (int i = 0; i < big.Length; i++) big[i] = (byte)' ';
            try { DisplayWire.Decode(big, big.Length); throw new Exception("oversize accepted"); }
            catch (WireError e) { Equal("oversize", e.Reason, "oversize"); }
            var bad = new byte[] { 0x7b, 0xff, 0xfe, 0x7d };
            try { DisplayWire.Decode(bad, bad.Length); throw new Exception("bad UTF-8 accepted"); }
            catch (WireError e) { Equal("encoding", e.Reason, "encoding"); }
            Rejects("json", "{" + ok + ",\"text\":\"a\"");
            Rejects("json", "{" + ok + ",\"text\":\"a\"} x");
            Rejects("json", new string('[', 100) + new string(']', 100));
            Rejects("non_finite", "{" + ok + ",\"text\":NaN}");
            Rejects("non_finite", "{\"version\":1,\"kind\":\"phrase\",\"seq\":1,\"stamp\":1e400,\"text\":\"\"}");
            Rejects("not_object", "[1,2]");
            Rejects("version", "{\"version\":2,\"kind\":\"phrase\"}");
            Rejects("type", "{\"version\":1.0,\"kind\":\"phrase\"}");
            Rejects("kind", "{\"version\":1,\"kind\":\"dance\",\"seq\":1,\"stamp\":1}");
            Rejects("missing_field", "{" + ok + "}");
            Rejects("type", "{" + ok + ",\"text\":5}");
            Rejects("range", "{" + ok + ",\"text\":\"" + new string('x', 201) + "\"}");
            Rejects("range", "{\"version\":1,\"kind\":\"phrase\",\"seq\":-1,\"stamp\":1,\"text\":\"\"}");
            Rejects("range", "{\"version\":1,\"kind\":\"dummies\",\"seq\":1,\"stamp\":1,\"set\":1,\"part\":2,\"parts\":2,\"radius_m\":0.05,\"positions\":[]}");
            Rejects("range", "{\"version\":1,\"kind\":\"event\",\"seq\":1,\"stamp\":1,\"event_id\":1,\"event\":\"won\",\"target\":\"\"}");
            Rejects("type", "{\"version\":1,\"kind\":\"targets\",\"seq\":1,\"stamp\":1,\"active\":\"\",\"targets\":[{\"id\":\"a\",\"position\":[1,2],\"role\":\"target\"}]}");
            Rejects("range", "{\"version\":1,\"kind\":\"targets\",\"seq\":1,\"stamp\":1,\"active\":\"\",\"targets\":[{\"id\":\"a\",\"position\":[1,2,3],\"role\":\"dummy\"}]}");
            Rejects("missing_field", "{\"version\":1,\"kind\":\"clock_ping\",\"ping_seq\":3}");
        });
        Test("a dummy set shows once all its parts arrived, and a newer set replaces it", () =>
        {
            var s = new DisplayState();
            uint seq = 10;
            Func<uint, uint, uint, int, string> part = (set, p, parts, count) =>
            {
                var sb = new StringBuilder("{\"version\":1,\"kind\":\"dummies\",\"seq\":" + (seq++) + ",\"stamp\":1,\"set\":" + set + ",\"part\":" + p + ",\"parts\":" + parts + ",\"radius_m\":0.05,\"positions\":[");
                for (int i = 0; i < count; i++) sb.Append(i > 0 ? "," : "").Append("[" + p + "," + i + ",2]");
                return sb.Append("]}").ToString();
            };
            s.Apply(Decode(part(1, 1, 2, 25)));
            Equal(0, s.Dummies.Count, "half a set is not shown");
            s.Apply(Decode(part(1, 0, 2, 25)));
            Equal(50, s.Dummies.Count, "the whole set");
            Equal(0.0, s.Dummies[0].X, "part 0 first");
            s.Apply(Decode(part(2, 0, 1, 3)));
            Equal(3, s.Dummies.Count, "set 2 replaces set 1");
            Equal(2u, s.DummySet, "set");
            s.Apply(Decode(part(0, 0, 1, 0)));
            Equal(0, s.Dummies.Count, "set 0 clears");
        });
        Test("each event shows once although it is sent three times, and stale seqs are dropped", () =>
        {
            var s = new DisplayState();
            var shown = new List<string>();
            s.EventShown += m => shown.Add(m.Event + ":" + m.Target);
            string ev = "{\"version\":1,\"kind\":\"event\",\"seq\":{0},\"stamp\":1,\"event_id\":{1},\"event\":\"found\",\"target\":\"t\"}";
            for (uint i = 0; i < 3; i++) s.Apply(Decode(ev.Replace("{0}", (100 + i).ToString()).Replace("{1}", "7")));
            Equal(1, shown.Count, "found once");
            s.Apply(Decode(ev.Replace("{0}", "50").Replace("{1}", "8")));
            Equal(1, s.Stale, "a message 52 behind is stale");
            Equal(1, shown.Count, "nothing shown for it");
            s.Apply(Decode(ev.Replace("{0}", "4294966000").Replace("{1}", "9")));   // 1298 behind
            Equal(2, shown.Count, "far behind: the PC restarted, shown");
            Equal(1, s.Restarts, "restart counted");
            for (uint i = 0; i < 200; i++) s.Apply(Decode(ev.Replace("{0}", (1 + i).ToString()).Replace("{1}", (1000 + i).ToString())));
            Equal(202, shown.Count, "all distinct events shown");
        });
        Test("seq wraps from 4294967295 to 0 on the wire", () =>
        {
            var clock = new StopwatchClock();
            using (var rx = new UdpClient(new IPEndPoint(IPAddress.Loopback, 0)))
            using (var link = new HeadsetLink(IPAddress.Loopback, ((IPEndPoint)rx.Client.LocalEndPoint).Port, new IPEndPoint(IPAddress.Loopback, 0), clock, 4294967294u))
            {
                rx.Client.ReceiveTimeout = 2000;
                for (int i = 0; i < 3; i++) link.SendGaze(Frame(0));
                var from = new IPEndPoint(IPAddress.Any, 0);
                string[] seqs = new string[3];
                for (int i = 0; i < 3; i++) seqs[i] = Json.Parse(Encoding.UTF8.GetString(rx.Receive(ref from))).Object["seq"].Text;
                Equal("4294967294,4294967295,0", string.Join(",", seqs), "seqs");
            }
        });
        Test("a ping over loopback is answered with its t1 verbatim and the headset's times", () =>
        {
            var clock = new StopwatchClock(500.0);
            using (var pc = new UdpClient(new IPEndPoint(IPAddress.Loopback, 0)))
            using (var link = new HeadsetLink(IPAddress.Loopback, ((IPEndPoint)pc.Client.LocalEndPoint).Port, new IPEndPoint(IPAddress.Loopback, 0), clock))
            {
                link.Start();
                link.Pump();   // the owner reads the clock once: from then on pings are answered
                byte[] ping = Encoding.UTF8.GetBytes("{\"version\":1,\"kind\":\"clock_ping\",\"ping_seq\":77,\"t1\":1234.5678901234567}");
                double before = clock.Now();
                pc.Send(ping, ping.Length, link.ListenEndPoint);
                string echo = ReceiveWhilePumping(pc, link.Pump, 3.0);
                double after = clock.Now();
                var o = Json.Parse(echo).Object;
                Equal("clock_echo", o["kind"].String, "kind");
                Equal("77", o["ping_seq"].Text, "ping_seq");
                Equal("1234.5678901234567", o["t1"].Text, "t1 verbatim");
                // t2 and t3 are Stopwatch ticks carried onto the clock: within a few microseconds of it.
                True(before - 1e-4 <= o["t2"].Number && o["t2"].Number <= o["t3"].Number && o["t3"].Number <= after + 1e-4, "t2, t3 within the exchange: " + echo);
                var deadline = DateTime.UtcNow.AddSeconds(3);   // counted just after the send returns
                while (link.Echoes == 0 && DateTime.UtcNow < deadline) Thread.Sleep(1);
                Equal(1, link.Echoes, "echoes");
            }
        });
        Test("downlink datagrams from another address are dropped", () =>
        {
            // The link listens to 127.0.0.2 as its PC; a datagram from 127.0.0.1 is someone else's.
            using (var stranger = new UdpClient(new IPEndPoint(IPAddress.Loopback, 0)))
            using (var link = new HeadsetLink(IPAddress.Parse("127.0.0.2"), 9, new IPEndPoint(IPAddress.Loopback, 0), new StopwatchClock()))
            {
                link.Start();
                byte[] ping = Encoding.UTF8.GetBytes("{\"version\":1,\"kind\":\"clock_ping\",\"ping_seq\":1,\"t1\":1}");
                stranger.Send(ping, ping.Length, link.ListenEndPoint);
                var deadline = DateTime.UtcNow.AddSeconds(3);
                while (link.Dropped == 0 && DateTime.UtcNow < deadline) Thread.Sleep(5);
                Equal(1, link.DroppedBy.ContainsKey("sender") ? link.DroppedBy["sender"] : 0, "dropped as sender");
                Equal(0, link.Echoes, "no echo to a stranger");
            }
        });
        Test("a lost-eye frame is skipped and counted, and seq does not advance for it", () =>
        {
            using (var rx = new UdpClient(new IPEndPoint(IPAddress.Loopback, 0)))
            using (var link = new HeadsetLink(IPAddress.Loopback, ((IPEndPoint)rx.Client.LocalEndPoint).Port, new IPEndPoint(IPAddress.Loopback, 0), new StopwatchClock()))
            {
                var lost = Frame(0);
                lost.GazeDirection = new Vec3(double.NaN, double.NaN, double.NaN);
                link.SendGaze(Frame(0));
                True(!link.SendGaze(lost), "lost eye sent");
                link.SendGaze(Frame(0));
                Equal(1, link.Skipped, "skipped");
                Equal(2u, link.NextSeq, "seq");
            }
        });

        Test("the clock and every callback are called on the owner thread only: the downlink survives Unity's clock", () =>
        {
            var clock = new MainThreadClock();
            using (var pc = new UdpClient(new IPEndPoint(IPAddress.Loopback, 0)))
            using (var link = new HeadsetLink(IPAddress.Loopback, ((IPEndPoint)pc.Client.LocalEndPoint).Port, new IPEndPoint(IPAddress.Loopback, 0), clock))
            {
                var received = new List<string>();
                var rejected = new List<string>();
                link.Received = m => { clock.Check("Received"); received.Add(m.Kind); };
                link.Rejected = r => { clock.Check("Rejected"); rejected.Add(r); };
                link.Display.EventShown += m => clock.Check("EventShown");
                link.Start();
                link.SendGaze(Frame(0));
                for (uint n = 1; n <= 3; n++)
                {
                    byte[] ping = Encoding.UTF8.GetBytes("{\"version\":1,\"kind\":\"clock_ping\",\"ping_seq\":" + n + ",\"t1\":5}");
                    pc.Send(ping, ping.Length, link.ListenEndPoint);
                    string echo;
                    do echo = ReceiveWhilePumping(pc, link.Pump, 3.0); while (!echo.Contains("clock_echo"));
                    Equal(n.ToString(), Json.Parse(echo).Object["ping_seq"].Text, "the echo of ping " + n);
                }
                byte[] ev = Encoding.UTF8.GetBytes("{\"version\":1,\"kind\":\"event\",\"seq\":1,\"stamp\":1,\"event_id\":1,\"event\":\"found\",\"target\":\"a\"}");
                byte[] junk = Encoding.UTF8.GetBytes("{\"version\":1,");
                pc.Send(ev, ev.Length, link.ListenEndPoint);
                pc.Send(junk, junk.Length, link.ListenEndPoint);
                var deadline = DateTime.UtcNow.AddSeconds(3);
                while ((rejected.Count == 0 || !received.Contains("event")) && DateTime.UtcNow < deadline) { link.Pump(); Thread.Sleep(2); }
                Equal(0, clock.OffThread, "calls off the owner thread");
                Equal(3, link.Echoes, "echoes");
                True(received.Contains("event") && received.Contains("clock_ping"), "Received on the owner: " + string.Join(",", received));
                Equal("json", rejected.Count > 0 ? rejected[0] : "", "Rejected on the owner");
            }
        });
        foreach (bool rendererFirst in new[] { true, false })
            Test("the renderer's Start " + (rendererFirst ? "before" : "after") + " the link's: it draws the display and its events", () =>
            {
                var clock = new MainThreadClock();
                using (var pc = new UdpClient(new IPEndPoint(IPAddress.Loopback, 0)))
                using (var session = new HeadsetSession(IPAddress.Loopback, ((IPEndPoint)pc.Client.LocalEndPoint).Port, new IPEndPoint(IPAddress.Loopback, 0), clock))
                {
                    var renderer = new Renderer();
                    if (rendererFirst) renderer.Start(session, clock);
                    session.Start();
                    if (!rendererFirst) renderer.Start(session, clock);
                    var head = new Vec3(0, 1.6, 0);
                    var still = new Quat(0, 0, 0, 1);
                    session.Update(null, head, still);
                    renderer.LateUpdate();
                    byte[] targets = Encoding.UTF8.GetBytes("{\"version\":1,\"kind\":\"targets\",\"seq\":1,\"stamp\":1,\"active\":\"a\",\"targets\":[{\"id\":\"a\",\"position\":[0,1.6,2],\"role\":\"target\"}]}");
                    byte[] found = Encoding.UTF8.GetBytes("{\"version\":1,\"kind\":\"event\",\"seq\":2,\"stamp\":1,\"event_id\":4,\"event\":\"found\",\"target\":\"a\"}");
                    pc.Send(targets, targets.Length, session.Link.ListenEndPoint);
                    pc.Send(found, found.Length, session.Link.ListenEndPoint);
                    var deadline = DateTime.UtcNow.AddSeconds(3);
                    while ((renderer.Targets != 1 || renderer.Flashed != "a") && DateTime.UtcNow < deadline)
                    {
                        session.Update(null, head, still);
                        renderer.LateUpdate();
                        Thread.Sleep(2);
                    }
                    Equal(1, renderer.Targets, "targets drawn");
                    Equal("a", renderer.Flashed, "found flashed");
                    Equal(0, clock.OffThread, "calls off the owner thread");
                }
            });
        Test("eyes not tracked (OpenXR's default pose): the head gaze is sent, marked not valid", () =>
        {
            var clock = new MainThreadClock();
            using (var rx = new UdpClient(new IPEndPoint(IPAddress.Loopback, 0)))
            using (var session = new HeadsetSession(IPAddress.Loopback, ((IPEndPoint)rx.Client.LocalEndPoint).Port, new IPEndPoint(IPAddress.Loopback, 0), clock))
            {
                session.Start();
                rx.Client.ReceiveTimeout = 2000;
                var from = new IPEndPoint(IPAddress.Any, 0);
                var head = new Vec3(0.1, 1.6, 0.2);
                var turned = new Quat(0, Math.Sin(Math.PI / 12), 0, Math.Cos(Math.PI / 12));   // Unity Euler(0, 30, 0): 30 deg right
                // Before consent or without an eye tracker OpenXR's pose reads (0,0,0) and (0,0,0,0).
                var eyes = new EyeSource { Tracked = false, Origin = new Vec3(0, 0, 0), Direction = new Vec3(0, 0, 0) };
                // A source that says tracked but gives no direction is not believed either; a stale pose
                // with tracking lost is not tracked.
                var claims = new EyeSource { Tracked = true, Origin = new Vec3(0, 0, 0), Direction = new Vec3(0, 0, 0) };
                var stale = new EyeSource { Tracked = false, Origin = new Vec3(0.1, 1.6, 0.2), Direction = new Vec3(-0.5, 0, 0.866) };
                foreach (var source in new[] { eyes, claims, stale })
                {
                    True(session.Update(source, head, turned), "sent");
                    var o = Json.Parse(Encoding.UTF8.GetString(rx.Receive(ref from))).Object;
                    Equal(JsonKind.False, o["eye_tracking_valid"].Kind, "eye_tracking_valid");
                    Equal(0.1, o["gaze_origin"].Array[0].Number, "origin: the head");
                    var d = o["gaze_direction"].Array;
                    True(Math.Abs(d[0].Number - 0.5) < 1e-9 && Math.Abs(d[1].Number) < 1e-9 && Math.Abs(d[2].Number - Math.Sqrt(0.75)) < 1e-9,
                         "direction: the head's forward, 30 deg right: " + d[0].Number + "," + d[1].Number + "," + d[2].Number);
                }
                var tracked = new EyeSource { Tracked = true, Origin = new Vec3(0.11, 1.6, 0.2), Direction = new Vec3(-0.2, 0.1, 0.97) };
                session.Update(tracked, head, turned);
                var t = Json.Parse(Encoding.UTF8.GetString(rx.Receive(ref from))).Object;
                Equal(JsonKind.True, t["eye_tracking_valid"].Kind, "tracked eyes are valid");
                Equal(-0.2, t["gaze_direction"].Array[0].Number, "the eye direction as given");
                Equal(0, clock.OffThread, "calls off the owner thread");
            }
        });
        Test("a confirm press goes out three times with one press_id and the clock at the press", () =>
        {
            var clock = new MainThreadClock();
            using (var rx = new UdpClient(new IPEndPoint(IPAddress.Loopback, 0)))
            using (var link = new HeadsetLink(IPAddress.Loopback, ((IPEndPoint)rx.Client.LocalEndPoint).Port, new IPEndPoint(IPAddress.Loopback, 0), clock))
            {
                double before = clock.Now();
                uint first = link.SendConfirm();
                double after = clock.Now();
                var got = new List<string>();
                var deadline = DateTime.UtcNow.AddSeconds(3);
                var from = new IPEndPoint(IPAddress.Any, 0);
                while (got.Count < 3 && DateTime.UtcNow < deadline)
                {
                    link.Pump();
                    while (rx.Available > 0) got.Add(Encoding.UTF8.GetString(rx.Receive(ref from)));
                    Thread.Sleep(2);
                }
                Equal(3, got.Count, "datagrams");
                True(got[0] == got[1] && got[1] == got[2], "the same datagram: " + string.Join(" ", got));
                var o = Json.Parse(got[0]).Object;
                Equal("confirm", o["kind"].String, "kind");
                Equal(first.ToString(), o["press_id"].Text, "press_id");
                True(before <= o["stamp"].Number && o["stamp"].Number <= after, "stamp at the press");
                Equal(first + 1, link.SendConfirm(), "the next press");
                Equal(0, clock.OffThread, "calls off the owner thread");
            }
        });

        int passed = 0, failed = 0;
        foreach (var t in All)
        {
            if (args.Length > 0 && !t.Key.Contains(args[0])) continue;
            try { t.Value(); passed++; }
            catch (Exception e) { failed++; Console.WriteLine("FAILED " + t.Key + ": " + e.Message); }
        }
        Console.WriteLine(passed + " passed, " + failed + " failed");
        return failed == 0 ? 0 : 1;
    }
}
