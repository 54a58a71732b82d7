// A PLC-side OPC UA client on node-opcua (an independent stack), driven by tests/gateway/test_node_opcua.py.
//
//   node plc.js URL SCENARIO[,SCENARIO…] [USER PASSWORD]   (one session per scenario, in order)
//
// Scenarios: browse (anonymous: browse paths, reads, a refused write and call), handshake and methods
// (Reset -> Idle -> Start -> a cycle -> Complete, watching StateCurrent by subscription and the Admin
// counters), bad-input. Prints one JSON object {scenario: result} on stdout; exits 1 on any unexpected error.
"use strict";

const {
  OPCUAClient,
  MessageSecurityMode,
  SecurityPolicy,
  AttributeIds,
  DataType,
  UserTokenType,
  makeBrowsePath,
  ClientSubscription,
  ClientMonitoredItem,
  TimestampsToReturn,
} = require("node-opcua-client");

const PACKML_NS = "http://opcfoundation.org/UA/PackML/";
const CELLCTL_NS = "urn:cellctl:opcua";
const IDLE = 4, COMPLETE = 17;

function sleep(ms) {
  return new Promise((r) => setTimeout(r, ms));
}

async function runScenario(session, scenario) {
  const out = { scenario };
  {
    const nsArray = await session.readNamespaceArray();
    const pk = nsArray.indexOf(PACKML_NS);
    const cc = nsArray.indexOf(CELLCTL_NS);
    out.namespaces = { packml: pk, cellctl: cc };
    const paths = {
      StateCurrent: `/Objects/${cc}:cell1/${pk}:Status/${cc}:StateCurrent`,
      UnitModeCurrent: `/Objects/${cc}:cell1/${pk}:Status/${pk}:UnitModeCurrent`,
      CmdRejectReason: `/Objects/${cc}:cell1/${pk}:Status/${cc}:CmdRejectReason`,
      CntrlCmd: `/Objects/${cc}:cell1/${cc}:Command/${cc}:CntrlCmd`,
      CmdChangeRequest: `/Objects/${cc}:cell1/${cc}:Command/${cc}:CmdChangeRequest`,
      ProdProcessedCount: `/Objects/${cc}:cell1/${pk}:Admin/${pk}:ProdProcessedCount`,
      ProdDefectiveCount: `/Objects/${cc}:cell1/${pk}:Admin/${pk}:ProdDefectiveCount`,
      LastOutcome: `/Objects/${cc}:cell1/${pk}:Admin/${cc}:LastCycle/${cc}:Outcome`,
      StateMachine: `/Objects/${cc}:cell1/${pk}:BaseStateMachine`,
      Reset: `/Objects/${cc}:cell1/${pk}:BaseStateMachine/${pk}:Reset`,
      Start: `/Objects/${cc}:cell1/${pk}:BaseStateMachine/${pk}:Start`,
    };
    const id = {};
    out.browse = {};
    for (const [name, bnf] of Object.entries(paths)) {
      const r = await session.translateBrowsePath(makeBrowsePath("RootFolder", bnf));
      out.browse[name] = r.statusCode.name;
      if (r.statusCode.isGood()) id[name] = r.targets[0].targetId;
    }
    const read = async (name) => (await session.read({ nodeId: id[name], attributeId: AttributeIds.Value })).value.value;
    const write = async (name, dataType, value) =>
      (await session.write({ nodeId: id[name], attributeId: AttributeIds.Value, value: { value: { dataType, value } } })).name;
    const call = async (name, inputArguments = []) => {
      const r = await session.call({ objectId: id.StateMachine, methodId: id[name], inputArguments });
      return { status: r.statusCode.name, reason: r.outputArguments && r.outputArguments[0] ? r.outputArguments[0].value : null };
    };
    const waitFor = async (name, want, ms) => {
      const end = Date.now() + ms;
      let v;
      while (Date.now() < end) {
        v = await read(name);
        if (v === want) return v;
        await sleep(20);
      }
      throw new Error(`${name} is ${v}, not ${want} after ${ms} ms`);
    };

    out.state = await read("StateCurrent");
    out.unit_mode = await read("UnitModeCurrent");
    if (scenario === "browse") {
      try {
        out.write_cntrl_cmd = await write("CntrlCmd", DataType.Int32, 1);
      } catch (err) {
        out.write_cntrl_cmd = String(err.message || err); // the whole Write service is refused
      }
      try {
        out.call_reset = (await call("Reset")).status;
      } catch (err) {
        out.call_reset = String(err.message || err);
      }
      out.state_after = await read("StateCurrent");
    } else if (scenario === "handshake" || scenario === "methods") {
      const seen = [];
      const sub = ClientSubscription.create(session, {
        requestedPublishingInterval: 10,
        requestedLifetimeCount: 600,
        requestedMaxKeepAliveCount: 20,
        maxNotificationsPerPublish: 100,
        publishingEnabled: true,
      });
      const item = ClientMonitoredItem.create(
        sub,
        { nodeId: id.StateCurrent, attributeId: AttributeIds.Value },
        { samplingInterval: 0, discardOldest: true, queueSize: 100 },
        TimestampsToReturn.Both,
      );
      item.on("changed", (dv) => seen.push({ v: dv.value.value, source: dv.sourceTimestamp && dv.sourceTimestamp.toISOString() }));
      // the first notification is the current value: from then on every change is seen
      const subscribed = Date.now() + 15000;
      while (seen.length === 0 && Date.now() < subscribed) await sleep(20);
      out.processed_before = await read("ProdProcessedCount");
      out.defective_before = await read("ProdDefectiveCount");
      out.steps = [];
      const command = async (name, code) => {
        if (scenario === "methods") {
          const r = await call(name);
          out.steps.push({ name, ...r });
        } else {
          const a = await write("CntrlCmd", DataType.Int32, code);
          const b = await write("CmdChangeRequest", DataType.Boolean, true);
          const reset = await read("CmdChangeRequest");
          out.steps.push({ name, cntrl_cmd: a, change_request: b, change_request_after: reset });
        }
      };
      await command("Reset", 1);
      await waitFor("StateCurrent", IDLE, 10000);
      await command("Start", 2);
      await waitFor("StateCurrent", COMPLETE, Number(process.env.PLC_CYCLE_TIMEOUT_MS || 30000));
      const end = Date.now() + 10000;
      while ((await read("ProdProcessedCount")) === out.processed_before && Date.now() < end) await sleep(20);
      out.processed_after = await read("ProdProcessedCount");
      out.defective_after = await read("ProdDefectiveCount");
      out.last_outcome = await read("LastOutcome");
      await sleep(200);
      out.states_seen = seen.map((s) => s.v);
      out.source_timestamps = seen.every((s) => s.source !== null && s.source !== undefined);
      await sub.terminate();
    } else if (scenario === "bad-input") {
      out.cntrl_cmd = {};
      for (const v of [0, 11, -1, 2147483647]) out.cntrl_cmd[v] = await write("CntrlCmd", DataType.Int32, v);
      out.cntrl_cmd_double = await write("CntrlCmd", DataType.Double, 2.0);
      out.cntrl_cmd_string = await write("CntrlCmd", DataType.String, "2");
      out.change_request_without_command = await write("CmdChangeRequest", DataType.Boolean, true);
      out.reject_reason = await read("CmdRejectReason");
      out.start_in_stopped = await call("Start");
      out.state_after = await read("StateCurrent");
    } else {
      throw new Error(`unknown scenario ${scenario}`);
    }
  }
  return out;
}

async function main() {
  const [url, scenarios, user, password] = process.argv.slice(2);
  const results = {};
  // one process for all scenarios (loading node-opcua takes seconds on a busy machine), a fresh
  // connection and session for each, as separate PLC programs would have
  for (const scenario of scenarios.split(",")) {
    const client = OPCUAClient.create({
      applicationName: "cellctl-test-plc",
      endpointMustExist: false,
      securityMode: MessageSecurityMode.None,
      securityPolicy: SecurityPolicy.None,
      connectionStrategy: { maxRetry: 2, initialDelay: 200, maxDelay: 1000 },
    });
    await client.connect(url);
    try {
      const anonymous = scenario === "browse" || !user;
      const session = await client.createSession(
        anonymous ? undefined : { type: UserTokenType.UserName, userName: user, password },
      );
      try {
        results[scenario] = await runScenario(session, scenario);
      } finally {
        await session.close();
      }
    } finally {
      await client.disconnect();
    }
  }
  process.stdout.write(JSON.stringify(results) + "\n");
}

main().then(
  () => process.exit(0),
  (err) => {
    process.stdout.write(JSON.stringify({ error: String((err && err.stack) || err) }) + "\n");
    process.exit(1);
  },
);
