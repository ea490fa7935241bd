// A command-line stand-in for the HoloLens app, built from the same core: it sends gaze frames
// from a pose file (or a still head) to gaze_bridge, answers clock pings and logs the display
// messages it receives. The tests and the bench run it against the real nodes; a lab can use it
// to try the PC side without a headset. `HeadsetHarness.exe --help` lists the options.
using System;
using System.Collections.Generic;
using System.Globalization;
using System.IO;
using System.Net;
using System.Text;
using System.Threading;
using FabricGuidance.Headset;

static class HeadsetHarness
{
    const string Usage = @"usage: mono HeadsetHarness.exe [options]
  --uplink HOST:PORT      where gaze and clock echoes go (gaze_bridge; default 127.0.0.1:5005)
  --listen ADDR:PORT      where display messages and pings arrive (default 127.0.0.1:0: any free port)
  --pc ADDR               the only address downlink datagrams are accepted from (default 127.0.0.1)
  --poses FILE            JSON lines, Unity world frame: {""gaze_origin"":[x,y,z],""gaze_direction"":[x,y,z],
                          ""head_position"":[x,y,z],""head_orientation"":[x,y,z,w],""valid"":true};
                          ""gaze_direction"":""nan"" stands for a lost eye (the frame is skipped)
  --rate HZ               frames per second (default 90)
  --frames N              stop sending after N frames (default: cycle the poses until --duration)
  --duration S            exit after S seconds (default 10)
  --seq-start N           the first seq (default 0)
  --restart-after K       after K frames the app restarts: seq from 0, a new clock origin
  --clock-offset S        headset clock = seconds since start + S (default 1000)
  --clock-drift-ppm P     the headset clock runs at 1 + P * 1e-6 (default 0)
  --culture NAME          the thread's culture (e.g. de-DE): the wire must not depend on it
  --log FILE              JSON lines of what was sent (with its stamp), skipped, received and dropped
  --confirm-at S[,S...]   press confirm at these seconds after the start (the clicker / air tap)
  --commands stdin        read commands from standard input, one a line: ""confirm"" presses confirm;
                          ""look X Y Z"" (Unity world frame, from the gaze origin) sets where the eyes look:
                          every frame from then on carries that direction (normalised), the head turns with
                          it (yaw and pitch, no roll) and stays where the pose puts it; a lost eye stays lost
  Presses are logged as {""t"":..,""confirm"":press_id,""stamp"":..}, looks as {""t"":..,""look"":[x,y,z]};
  the main thread sends them, as in the app.";

    static int Main(string[] args)
    {
        // Console's type initializer (and TextWriter's and TextReader's under it) runs here, on the
        // main thread, before any other thread exists. Mono lets a thread that waits on a type
        // initializer another thread is running see it unfinished when the two wait on each other:
        // with the stdin reader thread first to touch Console while this thread built the log's
        // StreamWriter, 1 start in about 40 under load died in Console.WriteLine with a
        // NullReferenceException in StreamWriter.WriteSpan (a newline array still null).
        TextWriter stdout = Console.Out, stderr = Console.Error;
        TextReader stdin = Console.In;
        var o = new Dictionary<string, string>
        {
            {"--uplink", "127.0.0.1:5005"}, {"--listen", "127.0.0.1:0"}, {"--pc", "127.0.0.1"}, {"--poses", ""},
            {"--rate", "90"}, {"--frames", "-1"}, {"--duration", "10"}, {"--seq-start", "0"}, {"--restart-after", "-1"},
            {"--clock-offset", "1000"}, {"--clock-drift-ppm", "0"}, {"--culture", ""}, {"--log", ""},
            {"--confirm-at", ""}, {"--commands", ""},
        };
        for (int i = 0; i < args.Length; i++)
        {
            if (args[i] == "--help" || args[i] == "-h") { stdout.WriteLine(Usage); return 0; }
            if (!o.ContainsKey(args[i]) || i + 1 >= args.Length) return Fail(args[i], o.ContainsKey(args[i]) ? "needs a value" : "unknown option");
            o[args[i]] = args[++i];
        }
        IPEndPoint uplink, listen;
        IPAddress pc;
        double rate, duration, offset, drift;
        long frames, restartAfter;
        uint seqStart;
        var inv = CultureInfo.InvariantCulture;
        if (!EndPoint(o["--uplink"], out uplink)) return Fail("--uplink", "needs HOST:PORT with an IP address");
        if (!EndPoint(o["--listen"], out listen)) return Fail("--listen", "needs ADDR:PORT with an IP address");
        if (!IPAddress.TryParse(o["--pc"], out pc)) return Fail("--pc", "is not an IP address");
        if (!double.TryParse(o["--rate"], NumberStyles.Float, inv, out rate) || !(rate > 0 && rate <= 10000)) return Fail("--rate", "needs a number in (0, 10000]");
        if (!double.TryParse(o["--duration"], NumberStyles.Float, inv, out duration) || !(duration > 0)) return Fail("--duration", "needs a positive number");
        if (!double.TryParse(o["--clock-offset"], NumberStyles.Float, inv, out offset)) return Fail("--clock-offset", "needs a number");
        if (!double.TryParse(o["--clock-drift-ppm"], NumberStyles.Float, inv, out drift) || Math.Abs(drift) > 10000) return Fail("--clock-drift-ppm", "needs a number within +-10000");
        if (!long.TryParse(o["--frames"], NumberStyles.Integer, inv, out frames)) return Fail("--frames", "needs an integer");
        if (!long.TryParse(o["--restart-after"], NumberStyles.Integer, inv, out restartAfter)) return Fail("--restart-after", "needs an integer");
        if (!uint.TryParse(o["--seq-start"], NumberStyles.None, inv, out seqStart)) return Fail("--seq-start", "needs an integer in 0..4294967295");
        if (o["--culture"] != "")
        {
            try
            {
                var culture = new CultureInfo(o["--culture"]);
                Thread.CurrentThread.CurrentCulture = culture;
                Thread.CurrentThread.CurrentUICulture = culture;
                CultureInfo.DefaultThreadCurrentCulture = culture;   // the receive thread too
            }
            catch (CultureNotFoundException) { return Fail("--culture", "is not a culture this runtime knows"); }
        }
        var confirmAt = new List<double>();
        foreach (string part in o["--confirm-at"].Split(new[] { ',' }, StringSplitOptions.RemoveEmptyEntries))
        {
            double at;
            if (!double.TryParse(part, NumberStyles.Float, inv, out at) || !(at >= 0)) return Fail("--confirm-at", "needs seconds >= 0, comma-separated");
            confirmAt.Add(at);
        }
        confirmAt.Sort();
        if (o["--commands"] != "" && o["--commands"] != "stdin") return Fail("--commands", "takes only 'stdin'");
        var commands = new System.Collections.Concurrent.ConcurrentQueue<string>();
        if (o["--commands"] == "stdin")
            new Thread(() => { string c; while ((c = stdin.ReadLine()) != null) commands.Enqueue(c.Trim()); }) { IsBackground = true }.Start();
        List<GazeFrame> poses;
        try { poses = o["--poses"] == "" ? new List<GazeFrame> { Still() } : ReadPoses(o["--poses"]); }
        catch (Exception e) { return Fail("--poses", e.Message); }

        TextWriter log = o["--log"] == "" ? null : new StreamWriter(o["--log"], false, new UTF8Encoding(false)) { AutoFlush = true };
        var clock = new StopwatchClock(offset, drift);
        HeadsetLink link;
        try { link = new HeadsetLink(pc, uplink.Port, listen, clock, seqStart); }
        catch (System.Net.Sockets.SocketException e) { return Fail("--listen", "cannot bind: " + e.Message); }
        object logLock = new object();
        Action<string> write = line => { if (log != null) lock (logLock) log.WriteLine(line); };
        link.Received = m => write("{\"t\":" + Json.Number(link.Clock.Now()) + ",\"msg\":" + Describe(m) + "}");
        link.Rejected = r => write("{\"t\":" + Json.Number(link.Clock.Now()) + ",\"dropped\":\"" + r + "\"}");
        link.Start();
        stdout.WriteLine("listening " + link.ListenEndPoint.Address + ":" + link.ListenEndPoint.Port);
        stdout.Flush();

        var watch = System.Diagnostics.Stopwatch.StartNew();
        long frame = 0;
        double period = 1.0 / rate;
        Vec3? look = null;   // where the eyes look (a `look` command), in place of the poses' direction
        while (watch.Elapsed.TotalSeconds < duration)
        {
            // A frame only once its time has come: the loop wakes every 5 ms at most.
            if ((frames < 0 || frame < frames) && watch.Elapsed.TotalSeconds >= frame * period)
            {
                if (restartAfter >= 0 && frame == restartAfter)
                    link.Restart(new StopwatchClock(offset / 2.0, drift));   // a new app: seq 0, another clock origin
                uint seq = link.NextSeq;
                GazeFrame pose = poses[(int)(frame % poses.Count)];
                if (look.HasValue && pose.GazeDirection.IsFinite)
                {
                    pose.GazeDirection = look.Value;
                    pose.HeadOrientation = Facing(look.Value);
                }
                if (link.SendGaze(pose))
                    write("{\"t\":" + Json.Number(link.Clock.Now()) + ",\"sent\":" + seq.ToString(inv) +
                          ",\"stamp\":" + Json.Number(link.LastStamp) + "}");
                else
                    write("{\"t\":" + Json.Number(link.Clock.Now()) + ",\"skipped\":\"nan\"}");
                frame++;
            }
            link.Pump();
            int presses = 0;
            while (confirmAt.Count > 0 && confirmAt[0] <= watch.Elapsed.TotalSeconds) { confirmAt.RemoveAt(0); presses++; }
            string command;
            while (commands.TryDequeue(out command))
            {
                Vec3 direction;
                if (command == "confirm") presses++;
                else if (command.StartsWith("look", StringComparison.Ordinal) && Look(command, out direction))
                {
                    look = direction;
                    write("{\"t\":" + Json.Number(link.Clock.Now()) + ",\"look\":[" + Json.Number(direction.X) + "," +
                          Json.Number(direction.Y) + "," + Json.Number(direction.Z) + "]}");
                }
                else if (command.StartsWith("look", StringComparison.Ordinal))
                    stderr.WriteLine("HeadsetHarness: command '" + command + "' needs three finite numbers, not all 0 (look X Y Z)");
                else if (command != "") stderr.WriteLine("HeadsetHarness: unknown command '" + command + "' (commands: confirm, look X Y Z)");
            }
            for (int i = 0; i < presses; i++)
            {
                uint id = link.SendConfirm();
                write("{\"t\":" + Json.Number(link.Clock.Now()) + ",\"confirm\":" + id.ToString(inv) +
                      ",\"stamp\":" + Json.Number(link.LastConfirmStamp) + "}");
            }
            // Sleep to the next frame's time (not a fixed sleep: a late frame does not shift the rest),
            // at most 5 ms: pings, display messages and presses are handled at least that often.
            double next = (frames >= 0 && frame >= frames ? double.PositiveInfinity : frame * period) - watch.Elapsed.TotalSeconds;
            if (next > 0) Thread.Sleep(TimeSpan.FromSeconds(Math.Min(next, 0.005)));
        }
        link.Dispose();
        stdout.WriteLine(string.Format(inv, "harness: sent {0}, skipped {1}, echoes {2}, display {3}, dropped {4}, confirms {5}",
            link.Sent, link.Skipped, link.Echoes, link.DisplayReceived, link.Dropped, link.Confirms));
        if (log != null) log.Dispose();
        return 0;
    }

    static int Fail(string option, string why)
    {
        Console.Error.WriteLine("HeadsetHarness: " + option + " " + why + " (--help lists the options)");
        return 2;
    }

    static bool EndPoint(string text, out IPEndPoint ep)
    {
        ep = null;
        int colon = text.LastIndexOf(':');
        IPAddress a;
        int port;
        if (colon < 0 || !IPAddress.TryParse(text.Substring(0, colon).Trim('[', ']'), out a) ||
            !int.TryParse(text.Substring(colon + 1), NumberStyles.None, CultureInfo.InvariantCulture, out port) || port > 65535)
            return false;
        ep = new IPEndPoint(a, port);
        return true;
    }

    /// <summary>`look X Y Z`: the direction, normalised (false: not three finite numbers, or too short).</summary>
    static bool Look(string command, out Vec3 direction)
    {
        direction = new Vec3();
        string[] words = command.Split(new[] { ' ', '\t' }, StringSplitOptions.RemoveEmptyEntries);
        if (words.Length != 4 || words[0] != "look") return false;
        var v = new double[3];
        for (int i = 0; i < 3; i++)
            if (!double.TryParse(words[i + 1], NumberStyles.Float, CultureInfo.InvariantCulture, out v[i]) || double.IsNaN(v[i]) || double.IsInfinity(v[i])) return false;
        double norm = Math.Sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        if (!(norm > GazeFrames.MinDirection)) return false;
        direction = new Vec3(v[0] / norm, v[1] / norm, v[2] / norm);
        return true;
    }

    /// <summary>The head facing `d` (unit, Unity world) without roll: Unity's Quaternion.Euler(pitch, yaw, 0),
    /// a yaw about y (positive turns right) after a pitch about x (positive looks down).</summary>
    static Quat Facing(Vec3 d)
    {
        double yaw = Math.Atan2(d.X, d.Z), pitch = -Math.Asin(Math.Max(-1.0, Math.Min(1.0, d.Y)));
        double sy = Math.Sin(yaw / 2), cy = Math.Cos(yaw / 2), sx = Math.Sin(pitch / 2), cx = Math.Cos(pitch / 2);
        return new Quat(cy * sx, sy * cx, -sy * sx, cy * cx);
    }

    static GazeFrame Still()
    {
        return new GazeFrame
        {
            GazeOrigin = new Vec3(0, 1.6, 0), GazeDirection = new Vec3(0, 0, 1),
            HeadPosition = new Vec3(0, 1.6, 0), HeadOrientation = new Quat(0, 0, 0, 1), EyeTrackingValid = true,
        };
    }

    static List<GazeFrame> ReadPoses(string path)
    {
        var list = new List<GazeFrame>();
        int line = 0;
        foreach (string text in File.ReadAllLines(path))
        {
            line++;
            if (text.Trim() == "") continue;
            if (list.Count >= 100000) throw new Exception(path + ": more than 100000 poses");
            JsonValue v;
            try { v = Json.Parse(text); }
            catch (JsonError e) { throw new Exception(path + ":" + line + ": " + e.Message); }
            if (v.Kind != JsonKind.Object) throw new Exception(path + ":" + line + ": not an object");
            var f = new GazeFrame
            {
                GazeOrigin = V3(v, "gaze_origin", path, line), HeadPosition = V3(v, "head_position", path, line),
                EyeTrackingValid = !v.Object.ContainsKey("valid") || v.Object["valid"].Kind == JsonKind.True,
            };
            JsonValue dir;
            if (v.Object.TryGetValue("gaze_direction", out dir) && dir.Kind == JsonKind.String && dir.String == "nan")
                f.GazeDirection = new Vec3(double.NaN, double.NaN, double.NaN);
            else
                f.GazeDirection = V3(v, "gaze_direction", path, line);
            var q = Numbers(v, "head_orientation", 4, path, line);
            f.HeadOrientation = new Quat(q[0], q[1], q[2], q[3]);
            list.Add(f);
        }
        if (list.Count == 0) throw new Exception(path + ": no poses");
        return list;
    }

    static Vec3 V3(JsonValue v, string name, string path, int line)
    {
        var n = Numbers(v, name, 3, path, line);
        return new Vec3(n[0], n[1], n[2]);
    }

    static double[] Numbers(JsonValue v, string name, int count, string path, int line)
    {
        JsonValue a;
        if (!v.Object.TryGetValue(name, out a) || a.Kind != JsonKind.Array || a.Array.Count != count)
            throw new Exception(path + ":" + line + ": " + name + " needs " + count + " numbers");
        var r = new double[count];
        for (int i = 0; i < count; i++)
        {
            if (a.Array[i].Kind != JsonKind.Number) throw new Exception(path + ":" + line + ": " + name + " needs numbers");
            r[i] = a.Array[i].Number;
        }
        return r;
    }

    /// <summary>A decoded downlink message as JSON, for the log.</summary>
    static string Describe(DownlinkMessage m)
    {
        var sb = new StringBuilder("{\"kind\":");
        Json.AppendString(sb, m.Kind);
        var inv = CultureInfo.InvariantCulture;
        if (m.Kind == "clock_ping")
            return sb.Append(",\"ping_seq\":").Append(m.PingSeq.ToString(inv)).Append(",\"t1\":").Append(Json.Number(m.T1)).Append('}').ToString();
        sb.Append(",\"seq\":").Append(m.Seq.ToString(inv)).Append(",\"stamp\":").Append(Json.Number(m.Stamp));
        switch (m.Kind)
        {
            case "targets":
                sb.Append(",\"active\":");
                Json.AppendString(sb, m.Active);
                sb.Append(",\"targets\":[");
                for (int i = 0; i < m.Targets.Count; i++)
                {
                    if (i > 0) sb.Append(',');
                    sb.Append("{\"id\":");
                    Json.AppendString(sb, m.Targets[i].Id);
                    sb.Append(",\"role\":");
                    Json.AppendString(sb, m.Targets[i].Role);
                    sb.Append(",\"position\":");
                    Point(sb, m.Targets[i].Position);
                    sb.Append('}');
                }
                sb.Append(']');
                break;
            case "dummies":
                sb.Append(",\"set\":").Append(m.Set.ToString(inv)).Append(",\"part\":").Append(m.Part.ToString(inv))
                  .Append(",\"parts\":").Append(m.Parts.ToString(inv)).Append(",\"radius_m\":").Append(Json.Number(m.RadiusM))
                  .Append(",\"positions\":[");
                for (int i = 0; i < m.Positions.Count; i++)
                {
                    if (i > 0) sb.Append(',');
                    Point(sb, m.Positions[i]);
                }
                sb.Append(']');
                break;
            case "event":
                sb.Append(",\"event_id\":").Append(m.EventId.ToString(inv)).Append(",\"event\":");
                Json.AppendString(sb, m.Event);
                sb.Append(",\"target\":");
                Json.AppendString(sb, m.Target);
                break;
            case "prompt":
                sb.Append(",\"text\":");
                Json.AppendString(sb, m.Text);
                sb.Append(",\"step\":").Append(m.Step.ToString(inv)).Append(",\"steps\":").Append(m.Steps.ToString(inv));
                break;
            case "phrase":
                sb.Append(",\"text\":");
                Json.AppendString(sb, m.Text);
                break;
        }
        return sb.Append('}').ToString();
    }

    static void Point(StringBuilder sb, Vec3 p)
    {
        sb.Append('[').Append(Json.Number(p.X)).Append(',').Append(Json.Number(p.Y)).Append(',').Append(Json.Number(p.Z)).Append(']');
    }
}
