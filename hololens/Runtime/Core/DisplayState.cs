// What the wearer should see now, built from display messages (docs/headset_wire_format.md).
// Messages arrive on the receive thread and are applied where the drawing happens (Unity's main
// thread) by Pump(), so the state itself needs no lock. Memory is bounded: at most one dummy set
// shown and one being assembled (8 parts of 25), the last EventMemory event ids.
using System.Collections.Concurrent;
using System.Collections.Generic;

namespace FabricGuidance.Headset
{
    public sealed class DisplayState
    {
        public const int EventMemory = 64;
        /// <summary>A display seq this far behind the newest is a restarted sender, not a stale message.</summary>
        public const uint RestartThreshold = 1000;
        public const int MaxQueued = 256;

        public string Active = "";
        public readonly List<DisplayTarget> Targets = new List<DisplayTarget>();
        public readonly List<Vec3> Dummies = new List<Vec3>();
        public uint DummySet;
        public double DummyRadiusM = 0.05;
        public string Prompt = "";
        public uint PromptStep, PromptSteps;
        public string Phrase = "";
        public int Applied, Stale, Restarts, Overflow;

        /// <summary>found / next / done, each event_id once (the PC sends each three times).</summary>
        public event System.Action<DownlinkMessage> EventShown;

        readonly ConcurrentQueue<DownlinkMessage> queue = new ConcurrentQueue<DownlinkMessage>();
        bool haveSeq;
        uint lastSeq;
        uint assemblingSet;
        readonly Dictionary<uint, List<Vec3>> parts = new Dictionary<uint, List<Vec3>>();
        uint assemblingParts;
        readonly HashSet<uint> seenEvents = new HashSet<uint>();
        readonly Queue<uint> eventOrder = new Queue<uint>();

        /// <summary>From any thread: queue a decoded display message (dropped when MaxQueued wait).</summary>
        public void Enqueue(DownlinkMessage m)
        {
            if (queue.Count >= MaxQueued) { Overflow++; return; }
            queue.Enqueue(m);
        }

        /// <summary>On the drawing thread: apply what has arrived. Returns how many were applied.</summary>
        public int Pump()
        {
            int n = 0;
            DownlinkMessage m;
            while (queue.TryDequeue(out m)) if (Apply(m)) n++;
            return n;
        }

        public bool Apply(DownlinkMessage m)
        {
            if (haveSeq)
            {
                uint ahead = unchecked(m.Seq - lastSeq);
                if (ahead == 0 || (ahead >= 0x80000000u && unchecked(0u - ahead) <= RestartThreshold)) { Stale++; return false; }
                if (ahead >= 0x80000000u) Restarts++;
            }
            haveSeq = true;
            lastSeq = m.Seq;
            Applied++;
            switch (m.Kind)
            {
                case "targets":
                    Active = m.Active;
                    Targets.Clear();
                    Targets.AddRange(m.Targets);
                    break;
                case "dummies": ApplyDummies(m); break;
                case "event":
                    if (seenEvents.Contains(m.EventId)) break;
                    seenEvents.Add(m.EventId);
                    eventOrder.Enqueue(m.EventId);
                    if (eventOrder.Count > EventMemory) seenEvents.Remove(eventOrder.Dequeue());
                    var shown = EventShown;
                    if (shown != null) shown(m);
                    break;
                case "prompt":
                    Prompt = m.Text;
                    PromptStep = m.Step;
                    PromptSteps = m.Steps;
                    break;
                case "phrase": Phrase = m.Text; break;
            }
            return true;
        }

        void ApplyDummies(DownlinkMessage m)
        {
            if (m.Set == 0) { DummySet = 0; Dummies.Clear(); parts.Clear(); return; }
            if (m.Set == DummySet) return;   // the refresh of the set on show
            if (m.Set != assemblingSet || m.Parts != assemblingParts)
            {
                parts.Clear();
                assemblingSet = m.Set;
                assemblingParts = m.Parts;
            }
            parts[m.Part] = m.Positions;
            if (parts.Count < assemblingParts) return;
            Dummies.Clear();
            for (uint p = 0; p < assemblingParts; p++) Dummies.AddRange(parts[p]);
            DummySet = m.Set;
            DummyRadiusM = m.RadiusM;
            parts.Clear();
        }
    }
}
